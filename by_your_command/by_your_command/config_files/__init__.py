"""Config files (no rclpy): finding one (`locate`) and loading its YAML with each value's place, for
errors that name the file and line (`located_yaml`). Prompts, commands, agents and graphs use it;
it uses none of them."""
