"""Recording runs to rosbag2 bags with MCAP storage (ROS-free core: bag, on rosbags' writer).

The rclpy side, which discovers topics and feeds a bag, is
supersafe_ros.ros_io.bag_recorder (``start_recorder(path) -> handle; handle.stop()``).
"""
