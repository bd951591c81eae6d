"""OpenAI GPT-Live (full duplex): the session (`provider`), its settings (`config`), server events
into ours (`events`), errors (`errors`), the real-time input stream (`input`)."""
