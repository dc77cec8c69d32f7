"""Stage, simulator, segmenter and estimator with one parameters file:

    ros2 launch rheo_ros rheo_ros.launch.py [params_file:=FILE] [fast:=true]

``fast:=true`` runs the simulator driving /clock and the stage on simulated time (as
fast as the nodes exchange messages). For a real stage and sensors, start only the
segmenter and estimator: ``nodes:=segmenter,estimator``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    params = LaunchConfiguration("params_file").perform(context)
    fast = LaunchConfiguration("fast").perform(context).lower() == "true"
    wanted = LaunchConfiguration("nodes").perform(context).split(",")
    extra = {"stage": [{"use_sim_time": fast}], "simulator": [{"simulator.clock": fast}]}
    return [Node(package="rheo_ros", executable=name, name=name, output="screen",
                 parameters=[params, *extra.get(name, [])])
            for name in ("simulator", "segmenter", "estimator", "stage") if name in wanted]


def generate_launch_description():
    default = os.path.join(get_package_share_directory("rheo_ros"), "config", "rheo_ros.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default, description="ROS 2 parameters file"),
        DeclareLaunchArgument("fast", default_value="false", description="simulator drives /clock"),
        DeclareLaunchArgument("nodes", default_value="simulator,segmenter,estimator,stage",
                              description="comma-separated nodes to start"),
        OpaqueFunction(function=_nodes),
    ])
