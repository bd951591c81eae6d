"""Gemini Live: the session (`provider`), server messages into our events (`events`), the API's
errors into `ProviderError`s (`errors`), session resumption handles (`resumption`)."""
