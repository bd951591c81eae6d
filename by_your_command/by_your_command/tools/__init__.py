"""The robot's own tools (docs/tools.md): tools.yaml → a catalog of JSON Schemas the model sees,
and the model's arguments → the request, goal, message or command. Pure Python: no ROS here
(ros/interfaces.py reads the installed interfaces for the bridge)."""
