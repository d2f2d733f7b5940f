"""Where frames come from: image folders, video files and ROS bags, read as grayscale frames."""
