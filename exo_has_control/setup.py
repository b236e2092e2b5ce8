from glob import glob

from setuptools import find_packages, setup

package_name = 'exo_has_control'

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
        'Hip and knee PD position controllers and the gait trajectory publisher of the '
        'exo_has exoskeleton.'
    ),
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'pd_controller = exo_has_control.pd_controller:main',
            'gait_publisher = exo_has_control.gait_publisher:main',
        ],
    },
)
