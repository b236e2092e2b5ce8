from setuptools import find_packages, setup

package_name = 'exo_has_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    # What pip installs with it where no ROS is (the bounds of requirements.txt); colcon
    # installs nothing of these (rosdep and requirements.txt do).
    install_requires=['setuptools', 'PyYAML>=6.0,<7', 'rosbags>=0.10.4,<0.12', 'mcap>=1.2,<2'],
    zip_safe=True,
    maintainer='exo_has developers',
    maintainer_email='dev@exo-has.invalid',
    description=(
        'What every exo_has package shares, free of rclpy: joint and topic names, the '
        'parameters-file reader, rosbag2 MCAP bags and the root of the errors.'
    ),
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'exo_has.commands': [
            'bag = exo_has_common.bag:main',
        ],
    },
)
