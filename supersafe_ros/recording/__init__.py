"""Recording runs to rosbag2-layout MCAP bags (ROS-free core: msgdefs, bag).

The rclpy side, which discovers topics and feeds a bag, is
supersafe_ros.ros_io.bag_recorder (``start_recorder(path) -> handle; handle.stop()``).
"""
