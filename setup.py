"""ament_python package definition for cvj_ros.

`colcon build` installs the node executables to ``lib/cvj_ros`` (setup.cfg), which is
where ``ros2 run cvj_ros <node>`` looks them up through the ament index. A plain
``pip install`` puts the same console scripts on the venv's PATH.
"""
from glob import glob

from setuptools import find_packages, setup

package_name = 'cvj_ros'

NODES = ['engine_node', 'coupling_node', 'load_node', 'monitor_node', 'replay_node', 'driver_node']

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # the measured tables (cvj_ros.measurements) ship inside the package
    package_data={package_name: ['data/davidbaev2023/*.csv', 'data/davidbaev2023/*.md']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config/scenes', glob('config/scenes/*.yaml')),
        ('share/' + package_name + '/config/params', glob('config/params/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/examples', glob('examples/*.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='cvj_ros developers',
    maintainer_email='cvj-ros@example.org',
    description='Virtual driveline for ROS 2 with exact coupling kinematics.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'cvj-sim = cvj_ros.cli:main',
            'driveline_composed = cvj_ros.composed:main',
        # each node's main() through its launcher (cvj_ros/nodes/entry.py: a Ctrl-C during the
        # node module's imports ends it quietly)
        ] + [f'{n} = cvj_ros.nodes.entry:{n}' for n in NODES],
    },
)
