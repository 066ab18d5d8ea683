"""gsp_platform_sim: Simulated Gough-Stewart platform node."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'gsp_platform_sim'

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
    description='Simulated Gough-Stewart platform node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'platform_sim = gsp_platform_sim.platform_sim_node:main',
        ],
    },
)
