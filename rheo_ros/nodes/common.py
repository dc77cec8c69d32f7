"""What every node shares: parameter declaration from the package's table, startup."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from rheo_ros.params import DEFAULTS, PARAM_HELP, check_params


def declare_all(node: Node) -> dict[str, Any]:
    """Declare the package's parameters (defaults, descriptions) and return their values.

    One table for every node, so one parameters file serves them all.
    """
    values = {}
    for name, default in DEFAULTS.items():
        text = PARAM_HELP.get(name, "see config/rheo_ros.yaml")
        # Dynamic typing: a file's "150" for a float parameter means 150.0, as in the CLI;
        # check_params below applies the one set of rules.
        node.declare_parameter(name, default, ParameterDescriptor(description=text, dynamic_typing=True))
        values[name] = node.get_parameter(name).value
    return check_params(values, f"node {node.get_name()}")


def run_node(make: Callable[[], Node]) -> None:
    """Init, spin until Ctrl-C or SIGTERM, clean up; bad parameters end in one line."""
    rclpy.init(args=sys.argv)
    node = None
    try:
        node = make()
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    except (ValueError, KeyError) as exc:  # ParamsError is a ValueError
        print(f"{sys.argv[0]}: error: {exc}", file=sys.stderr)
        sys.exit(2)
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
