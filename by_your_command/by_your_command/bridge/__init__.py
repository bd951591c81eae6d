"""The ROS ⇄ agent WebSocket bridge without ROS: rosbridge v2 protocol, policy, server core, client."""
