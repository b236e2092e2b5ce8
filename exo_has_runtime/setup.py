from glob import glob

from setuptools import find_packages, setup

package_name = 'exo_has_runtime'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='exo_has developers',
    maintainer_email='dev@exo-has.invalid',
    description=(
        'What exo_has adds to rclpy: the recorder, replay and bag tools, period timing, '
        'real-time priority, launch-free process helpers for tests and the exo-has command.'
    ),
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'exo-has = exo_has_runtime.cli:main',
            'command_talker = exo_has_runtime.examples.command_talker:main',
            'state_echo = exo_has_runtime.examples.state_echo:main',
            'recorder = exo_has_runtime.recorder:main',
            'container = exo_has_runtime.container:main',
        ],
        'exo_has.commands': [
            'replay = exo_has_runtime.replay:main',
        ],
    },
)
