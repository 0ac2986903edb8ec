"""Monitor one galvano scanner: galvo_driver (optional), sysid and watchdog in one namespace.

    ros2 launch galvo_sysid monitor.launch.py
    ros2 launch galvo_sysid monitor.launch.py namespace:=scanner_1 model:=/path/scanner.yaml
    ros2 launch galvo_sysid monitor.launch.py driver:=false sysid_params_file:=/path/sysid.yaml

Arguments (``ros2 launch galvo_sysid monitor.launch.py --show-args``):

- ``namespace``: the scanner's namespace ('' none; ``scanner_1`` gives /scanner_1/galvo/...).
- ``model``: plant-model file for all three nodes ('' the nodes' own ``model`` parameter).
- ``driver``: start the simulated scanner (``false`` when a real scanner publishes the moves).
- ``params_file``: a parameter file for every node (its sections ``/**/sysid:``, ... or
  ``/**:`` say which node takes what); ``galvo_driver_params_file``, ``sysid_params_file``,
  ``watchdog_params_file``: one node's file, after the common one. ``model`` wins over them.

Where ``launch`` is not installed (ROS 2 from PyPI), ``galvo-sysid launch`` starts the same
nodes with the same arguments (``--namespace``, ``--model``, ``--no-driver``,
``--params-file [NODE=]FILE``): galvo_sysid/field/launcher.py, which a test keeps in step with
this file's arguments.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

NODES = ('galvo_driver', 'sysid', 'watchdog')

ARGUMENTS = {
    'namespace': ('', "the scanner's namespace ('': none)"),
    'model': ('', "plant-model file for all three nodes ('': the nodes' own model parameter)"),
    'driver': ('true', 'start the simulated scanner galvo_driver (false: a real scanner '
                       'publishes the moves)'),
    'params_file': ('', "parameter file for every node ('': none)"),
    **{f'{node}_params_file': ('', f"parameter file for {node} only ('': none)")
       for node in NODES},
}


def _nodes(context: object, *args: object, **kwargs: object) -> list[object]:
    """Build the node actions for the arguments given (as galvo-sysid launch its commands)."""
    value = {name: LaunchConfiguration(name).perform(context).strip() for name in ARGUMENTS}
    namespace = value['namespace'].strip('/')
    driver = value['driver'].lower() in ('true', '1', 'yes', 'on')
    actions: list[object] = []
    for node in NODES:
        if node == 'galvo_driver' and not driver:
            continue
        parameters = [f for f in (value['params_file'], value[f'{node}_params_file']) if f]
        if value['model']:
            parameters.append({'model': value['model']})
        actions.append(Node(package='galvo_sysid', executable=node, name=node,
                            namespace=namespace, parameters=parameters, output='screen',
                            emulate_tty=True))
    return actions


def generate_launch_description() -> object:
    """Describe the launch: the arguments, then the nodes."""
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in ARGUMENTS.items()),
        OpaqueFunction(function=_nodes),
    ])
