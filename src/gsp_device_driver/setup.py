"""gsp_device_driver: Measuring device driver node (sim and replay backends)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'gsp_device_driver'

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
    description='Measuring device driver node (sim and replay backends).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'device_driver = gsp_device_driver.device_driver_node:main',
        ],
    },
)
