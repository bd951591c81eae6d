"""What OpenAI's two speech APIs (Realtime in `openai_realtime/`, GPT-Live in `gpt_live/`) share: the
account and its front door (`errors`: keys, quota, rate limits, a refused upgrade) and the SDK's
WebSocket (`connection`: client, options, handshake, release). Their wire protocols differ and stay
in their own folders."""
