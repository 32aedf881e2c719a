"""Language-guided world models on Messenger-WM: the ROS-free core."""

__version__ = "0.1.0"
