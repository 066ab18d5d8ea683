"""The main job through both hardware paths at once: the platform through platform_bridge and
the emulated ros2_control controller, the device through gsp_fake_device on a pty and the
serial backend. Calibrates, applies to the bridge, validates."""

import json
import re
from pathlib import Path

from gsp_testing import marked_environment, marked_processes, run_demo, wait_until


def test_main_job_through_ros2_control_and_the_serial_device(tmp_path):
    env, marker = marked_environment()
    env.pop('ROS_DOMAIN_ID', None)  # the demo chooses a private one
    completed, output = run_demo(
        [
            '--output-root',
            str(tmp_path / 'runs'),
            '--postures',
            '20',
            '--validation-postures',
            '10',
            '--platform',
            'ros2_control',
            '--device',
            'serial',
        ],
        env,
    )
    assert completed.returncode == 0, output
    # Nothing the demo started is left (each node has a session of its own, so look for the
    # environment they inherited; the wait only bounds a failure while they are reaped).
    wait_until(lambda: not marked_processes(marker), 30.0)
    assert marked_processes(marker) == [], output
    assert 'applied to /platform_bridge' in output
    run = Path(re.findall(r'^run directory: (.+)$', completed.stdout, re.MULTILINE)[-1])
    for name in ('platform_bridge.log', 'controller_sim.log', 'gsp_fake_device.log'):
        assert (run / name).is_file(), name
    # The readings came through the serial backend from the emulated device on its pty.
    driver_log = (run / 'device_driver.log').read_text()
    assert "device_driver ready: backend 'serial'" in driver_log, driver_log
    assert re.search(r'serial device connected on \S+/gsp_device at \d+ baud', driver_log), (
        driver_log
    )
    assert "backend 'sim'" not in driver_log
    summary = json.loads((run / 'summary.json').read_text())
    before, after = summary['validation']['before'], summary['validation']['after']
    assert after['position_mm_mean'] < 0.01 * before['position_mm_mean']
    assert after['position_mm_max'] < 0.05 and after['orientation_deg_max'] < 0.01
