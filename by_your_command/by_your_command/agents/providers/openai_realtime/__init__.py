"""OpenAI Realtime (GA): the session (`provider`), server events into ours (`events`), the API's
errors into `ProviderError`s (`errors`)."""
