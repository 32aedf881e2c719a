"""ROS 2 nodes of the LWM system: thin adapters from JSON messages to lwm_models calls."""
