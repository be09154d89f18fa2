"""Export recordings: the BorealHDR folder tree (16-bit PNG per camera and exposure) and ROS 1 bags."""
