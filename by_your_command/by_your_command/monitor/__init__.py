"""The live monitor (docs/monitor.md): the web page the bridge serves, and agent metrics summarised
for the page, /diagnostics and the `agent_summary` topic. No ROS here: the bridge node wires it up."""
