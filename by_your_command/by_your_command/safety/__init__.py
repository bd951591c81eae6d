"""The safety stop: a local spotter for stop phrases that hears the microphone in every state."""
