"""Connection helpers shared by the providers, the emulators and the bridge (no ROS): a websockets
logger that never writes handshake headers, and the reconnect backoff."""
