"""Audio building blocks without ROS: PCM conversion, resampling, WAV files, devices, echo control."""
