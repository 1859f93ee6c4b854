"""Launch line_odom: parameters file, topic remappings, use_sim_time, optional rviz.

    ros2 launch line_odom line_odom.launch.py preset:=kitti_hdl64 points:=/kitti/points use_sim_time:=true
    ros2 launch line_odom line_odom.launch.py preset:=tum_kinect depth_image:=/camera/depth/image \
        camera_info:=/camera/depth/camera_info rviz:=true
    ros2 launch line_odom line_odom.launch.py params_file:=my_robot.yaml guess_odom:=/wheel/odometry
        (my_robot.yaml with guess: enabled: true - docs/NODE.md, "Motion guess")
    ros2 launch line_odom line_odom.launch.py params_file:=my_robot.yaml imu:=/imu/data
        (my_robot.yaml with imu: enabled: true - docs/NODE.md, "IMU rotation guess")
    ros2 launch line_odom line_odom.launch.py lifecycle:=true   (the managed node, for a lifecycle manager)

The node also gets the shipped Fast DDS large-message profile (config/fastdds_large_messages.xml) unless
fastdds_profile:=<other file> is given; export the same profile for the driver (see docs/NODE.md).
"""
import os


def _share(*parts):
    from ament_index_python.packages import get_package_share_directory

    return os.path.join(get_package_share_directory("line_odom"), *parts)


def generate_launch_description():
    # imported here so that this file stays importable (and testable) where the launch packages are absent
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument
    from launch.conditions import IfCondition
    from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
    from launch_ros.actions import Node
    from launch_ros.parameter_descriptions import ParameterValue

    preset = LaunchConfiguration("preset")
    params_file = LaunchConfiguration("params_file")
    use_sim_time = LaunchConfiguration("use_sim_time")
    profile = LaunchConfiguration("fastdds_profile")
    arguments = [
        DeclareLaunchArgument("preset", default_value="kitti_hdl64",
                              description="kitti_hdl64, tum_kinect, vlp16, ouster_os128 (defaults of every parameter)"),
        DeclareLaunchArgument("params_file",
                              default_value=PathJoinSubstitution([_share("config"),
                                                                  PythonExpression(["'", preset, "' + '.yaml'"])]),
                              description="ROS 2 parameter file (line_odom: ros__parameters: ...)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="use /clock (bag replay)"),
        DeclareLaunchArgument("namespace", default_value="", description="node namespace"),
        DeclareLaunchArgument("points", default_value="points", description="PointCloud2 input topic"),
        DeclareLaunchArgument("depth_image", default_value="depth/image", description="depth Image topic"),
        DeclareLaunchArgument("camera_info", default_value="depth/camera_info", description="CameraInfo topic"),
        DeclareLaunchArgument("guess_odom", default_value="guess_odom",
                              description="nav_msgs/Odometry motion guess (wheel odometry) topic, read with "
                                          "guess.enabled: true in the parameter file"),
        DeclareLaunchArgument("imu", default_value="imu",
                              description="sensor_msgs/Imu topic whose gyro turns the prediction, read with "
                                          "imu.enabled: true in the parameter file"),
        DeclareLaunchArgument("odom", default_value="odom", description="Odometry output topic"),
        DeclareLaunchArgument("path", default_value="path", description="Path output topic"),
        DeclareLaunchArgument("fastdds_profile", default_value=_share("config", "fastdds_large_messages.xml"),
                              description="Fast DDS XML profile for the node (large clouds on one host)"),
        DeclareLaunchArgument("initialpose", default_value="/initialpose",
                              description="geometry_msgs/PoseWithCovarianceStamped (rviz's 2D Pose Estimate) resetting "
                                          "the odometry to a pose in odom_frame"),
        DeclareLaunchArgument("lifecycle", default_value="false",
                              description="start the managed node (lifecycle_node: configure/activate through "
                                          "lifecycle_msgs, e.g. by Nav2's lifecycle manager)"),
        DeclareLaunchArgument("rviz", default_value="false", description="start rviz2 with rviz/line_odom.rviz"),
    ]
    node = Node(
        package="line_odom",
        executable=PythonExpression(["'lifecycle_node' if '", LaunchConfiguration("lifecycle"),
                                     "'.lower() == 'true' else 'node'"]),
        name="line_odom",
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[
            {"preset": preset},
            params_file,
            {"use_sim_time": ParameterValue(use_sim_time, value_type=bool)},
        ],
        remappings=[
            ("points", LaunchConfiguration("points")),
            ("depth/image", LaunchConfiguration("depth_image")),
            ("depth/camera_info", LaunchConfiguration("camera_info")),
            ("guess_odom", LaunchConfiguration("guess_odom")),
            ("imu", LaunchConfiguration("imu")),
            ("odom", LaunchConfiguration("odom")),
            ("path", LaunchConfiguration("path")),
            ("initialpose", LaunchConfiguration("initialpose")),
        ],
        additional_env={"FASTDDS_DEFAULT_PROFILES_FILE": profile, "FASTRTPS_DEFAULT_PROFILES_FILE": profile},
    )
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        name="rviz2",
        arguments=["-d", _share("rviz", "line_odom.rviz")],
        parameters=[{"use_sim_time": ParameterValue(use_sim_time, value_type=bool)}],
        condition=IfCondition(LaunchConfiguration("rviz")),
    )
    return LaunchDescription(arguments + [node, rviz])
