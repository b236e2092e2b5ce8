from glob import glob

from setuptools import find_packages, setup

package_name = 'exo_has_driver'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/config/canopen', glob('config/canopen/*')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='exo_has developers',
    maintainer_email='dev@exo-has.invalid',
    description=(
        'Hardware driver (CANopen motor drives and sensor board) and safety watchdog of '
        'the exo_has exoskeleton.'
    ),
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'watchdog = exo_has_driver.watchdog:main',
            'driver = exo_has_driver.driver_node:main',
            'can_devices = exo_has_driver.devices.main:main',
        ],
    },
)
