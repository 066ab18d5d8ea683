"""gsp_kinematics: pure numpy/scipy core (ament_python, also pip-installable)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'gsp_kinematics'

data_files = [
    ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
    ('share/' + package_name, ['package.xml']),
]
# The default geometries ship twice: as package data (importlib.resources, pip installs)
# and under share/<pkg>/config (ament_index, colcon installs).
config_files = sorted(glob(package_name + '/data/*.yaml'))
if config_files:
    data_files.append(('share/' + package_name + '/config', config_files))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={package_name: ['data/*.yaml']},
    data_files=data_files,
    install_requires=['setuptools', 'numpy', 'scipy', 'pyyaml'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='gsp-calibration maintainers',
    maintainer_email='maintainers@gsp-calibration.org',
    description='Gough-Stewart platform kinematics and calibration core (numpy/scipy, no ROS).',
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={
        'console_scripts': [
            'gsp_paper = gsp_kinematics.paper:main',
            'gsp_bench = gsp_kinematics.bench:main',
        ],
    },
)
