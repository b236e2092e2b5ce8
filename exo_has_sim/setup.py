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
    # What pip installs with it where no ROS is, for the diagnosis (the bounds of
    # requirements.txt): `pip install ./exo_has_common ./exo_has_sim`; the extra 'dask' adds
    # what --scheduler needs. colcon installs nothing of these (rosdep and requirements.txt do).
    install_requires=['setuptools', 'exo_has_common', 'numpy>=1.24,<2.6', 'scipy>=1.10,<2',
                      'numba>=0.60,<0.69', 'PyYAML>=6.0,<7', 'matplotlib>=3.7,<4'],
    extras_require={'dask': ['dask[distributed]>=2024.8,<2027']},
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
            'plant = exo_has_sim.plant_command:main',
            # The diagnosis where no ROS workspace gives `exo-has diagnose`.
            'exo-has-diagnose = exo_has_sim.diagnosis.cli:main',
        ],
        'exo_has.commands': [
            'design-check = exo_has_sim.design_check:main',
            'diagnose = exo_has_sim.diagnosis.cli:main',
        ],
    },
)
