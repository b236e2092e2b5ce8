from setuptools import find_packages, setup

package_name = 'exo_has_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='exo_has developers',
    maintainer_email='dev@exo-has.invalid',
    description=(
        'The running of the whole exo_has exoskeleton without launch files: session plans and '
        'their processes, on one host or two, exo-has demo and its report.'
    ),
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'robot_loop = exo_has_bringup.robot_main:main',
            'robot_bridge = exo_has_bringup.robot_bridge:main',
        ],
        'exo_has.commands': [
            'demo = exo_has_bringup.demo:main',
        ],
    },
)
