"""ament_python package set-up for tiltrov_ros.

The ROS 2 client libraries (rclpy and the message packages) are deliberately
absent from ``install_requires``: inside a ROS 2 install they come from the
distribution, and in the stand-alone virtual environment they come from
``requirements/ros-jazzy.txt`` (see the Makefile). Listing them here would make
a colcon build pull a second rclpy from PyPI.
"""

from glob import glob

from setuptools import find_packages, setup

package_name = 'tiltrov_ros'

# Executables that `ros2 run tiltrov_ros <name>` finds (setup.cfg puts them in
# lib/tiltrov_ros) and that a venv install puts on PATH.
console_scripts = [
    'tiltrov = tiltrov_ros.cli:main',
    'bag_recorder = tiltrov_ros.nodes.bag_recorder:main',
    'plant_simulator = tiltrov_ros.nodes.plant_simulator:main',
    'wrench_controller = tiltrov_ros.nodes.wrench_controller:main',
    'thrust_allocator = tiltrov_ros.nodes.thrust_allocator:main',
    'reference_publisher = tiltrov_ros.nodes.reference_publisher:main',
]

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + ['config/fastdds.xml']),
        ('share/' + package_name + '/config/scenarios', glob('config/scenarios/*.yaml')),
        ('share/' + package_name + '/config/foxglove', glob('config/foxglove/*.json')),
        ('share/' + package_name + '/config/plotjuggler', glob('config/plotjuggler/*.xml')),
        ('share/' + package_name + '/config/rviz', glob('config/rviz/*.rviz')),
        ('share/' + package_name + '/urdf', glob('urdf/*.urdf')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/config/campaigns', glob('config/campaigns/*.yaml')),
    ],
    python_requires='>=3.11',
    # numba compiles the hot paths (tiltrov_ros/core/jit.py); without it the numpy
    # reference runs (same answers, slower), with one warning.
    install_requires=['setuptools', 'numpy>=1.26', 'scipy>=1.11', 'PyYAML>=6.0', 'numba>=0.60'],
    extras_require={
        # Bag tools and figures.
        'bags': ['mcap>=1.2', 'mcap-ros2-support>=0.5', 'rosbags>=0.10',
                 'zstandard>=0.22', 'matplotlib>=3.8'],
        # `tiltrov campaign`: Monte-Carlo runs on Dask (a local cluster by default),
        # figures of the summary.
        'campaign': ['dask>=2024.8', 'distributed>=2024.8', 'matplotlib>=3.8'],
        # Everything `make test` needs besides the ROS wheels.
        'dev': ['pytest>=8', 'pytest-timeout>=2.3', 'pytest-xdist>=3.5', 'hypothesis>=6.100',
                'ruff>=0.6', 'mypy>=1.10', 'types-PyYAML',
                'colcon-common-extensions>=0.3'],
    },
    zip_safe=True,
    maintainer='tiltrov_ros developers',
    maintainer_email='tiltrov-ros@example.com',
    description='Underwater robot with four tilting thrusters: simulation, '
                'hierarchical PD control and thrust allocation for ROS 2 Jazzy.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={'console_scripts': console_scripts},
)
