"""Sessions in robotics formats: MCAP export with ROS 2 messages (Foxglove, Rerun, ROS 2) and
import of robot bags (MCAP, rosbag2, ROS 1) into sessions."""
