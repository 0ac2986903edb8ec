"""ament_python package definition of galvo_sysid (colcon and pip both build it)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'galvo_sysid'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, f'{PACKAGE}.*']),
    package_data={f'{PACKAGE}.model': ['data/*.yaml'], PACKAGE: ['data/*.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml') + glob('config/*.xml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.launch.py')),
        (f'share/{PACKAGE}/models', glob(f'{PACKAGE}/model/data/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='galvo_sysid developers',
    maintainer_email='galvo-sysid@example.org',
    description='Online system identification and drift monitoring of galvano scanners.',
    license='Apache-2.0',
    python_requires='>=3.11',
    entry_points={
        'console_scripts': [
            f'galvo_driver = {PACKAGE}.nodes.command_line:galvo_driver',
            f'sysid = {PACKAGE}.nodes.command_line:sysid',
            f'watchdog = {PACKAGE}.nodes.command_line:watchdog',
            f'galvo-sysid = {PACKAGE}.cli.main:main',
        ],
    },
)
