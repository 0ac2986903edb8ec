"""The ament_python layout builds with colcon and installs where `ros2 run` looks.

`ros2 run` itself is not installable from PyPI, so this checks what it relies on: the
executables in ``<install>/galvo_sysid/lib/galvo_sysid/``, the ament index marker and the
package manifest in ``share``.
"""

from __future__ import annotations

import os
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

EXECUTABLES = ('galvo_driver', 'sysid', 'watchdog', 'galvo-sysid')


def test_package_xml_is_format_3(repo: Path) -> None:
    root = ET.parse(repo / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'galvo_sysid'
    assert root.findtext('export/build_type') == 'ament_python'
    msgs = ET.parse(repo / 'msg_defs' / 'package.xml').getroot()
    assert msgs.findtext('name') == 'galvo_sysid_msgs'
    assert msgs.findtext('member_of_group') == 'rosidl_interface_packages'


def test_colcon_build_installs_executables(repo: Path, venv_bin: Path, tmp_path: Path) -> None:
    env = dict(os.environ, PATH=f'{venv_bin}:{os.environ.get("PATH", "")}')
    result = subprocess.run(
        [str(venv_bin / 'colcon'), '--log-base', str(tmp_path / 'log'), 'build',
         '--base-paths', str(repo), '--packages-select', 'galvo_sysid',
         '--build-base', str(tmp_path / 'build'), '--install-base', str(tmp_path / 'install'),
         '--event-handlers', 'console_direct-'],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    prefix = tmp_path / 'install' / 'galvo_sysid'
    for exe in EXECUTABLES:
        path = prefix / 'lib' / 'galvo_sysid' / exe
        assert path.is_file(), f'{exe} missing from {path.parent}'
        assert os.access(path, os.X_OK)
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'galvo_sysid').is_file()
    assert (prefix / 'share' / 'galvo_sysid' / 'package.xml').is_file()
