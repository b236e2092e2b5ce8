from glob import glob

from setuptools import find_packages, setup

package_name = 'exo_has_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    package_data={package_name: ['data/*.csv', 'data/README.md', 'data/emps/*']},
    include_package_data=True,
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='exo_has developers',
    maintainer_email='dev@exo-has.invalid',
    description=(
        'Hydraulic actuating system (HAS) plant model, simulation nodes and model-error '
        'diagnosis for the exo_has exoskeleton.'
    ),
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'plant = exo_has_sim.plant_node:main',
        ],
        'exo_has.commands': [
            'design-check = exo_has_sim.design_check:main',
            'diagnose = exo_has_sim.diagnosis.cli:main',
        ],
    },
)
