"""gsp_msgs_py: Names, QoS profiles, units and message conversions for gsp-calibration."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'gsp_msgs_py'

data_files = [
    ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
    ('share/' + package_name, ['package.xml']),
]
config_files = sorted(glob('config/*.yaml'))
if config_files:
    data_files.append(('share/' + package_name + '/config', config_files))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=data_files,
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='gsp-calibration maintainers',
    maintainer_email='maintainers@gsp-calibration.org',
    description='Names, QoS profiles, units and message conversions for gsp-calibration.',
    license='Apache-2.0',
)
