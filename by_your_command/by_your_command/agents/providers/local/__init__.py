"""The provider that runs the local speech engine (by_your_command/local_speech/), offline: no network,
no key. The session (`provider`), its settings (`config`), the engine behind it (`engine`), typed
text matched as speech (`text`), what it answers (`replies`)."""
