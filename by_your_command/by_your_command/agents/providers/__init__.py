"""Vendor sessions behind the `Provider` protocol (agents/provider.py); each imports its own SDK."""
