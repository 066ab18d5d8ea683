"""gsp_calibrator: Calibration node, demo, client and offline re-identification."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'gsp_calibrator'

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
    description='Calibration node, demo, client and offline re-identification.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'calibrator = gsp_calibrator.calibrator_node:main',
            'gsp_demo = gsp_calibrator.demo:main',
            'gsp_calibrate_client = gsp_calibrator.client:main',
            'gsp_reidentify = gsp_calibrator.offline:main',
            'replay = gsp_calibrator.replay_node:main',
        ],
    },
)
