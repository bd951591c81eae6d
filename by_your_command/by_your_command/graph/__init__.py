"""The graph description: profiles -> nodes (executable, parameters, remappings, namespace) and agents.

One description, two front ends: launch files (launch_actions.py, full ROS installs) and `byc up`
(processes.py + supervisor.py, pip-only installs). Nothing here imports ROS. docs/launch.md.
"""
