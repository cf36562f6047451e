"""cvj_ros: a ROS 2 virtual driveline with exact coupling kinematics."""

__version__ = '0.1.0'
