"""Everything the project starts keeps DDS on loopback: every socket of a running node is bound to 127.0.0.1."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from robot_localization_suite.launch.dds import loopback_environment

ROOT = Path(__file__).resolve().parent.parent
LOOPBACK_V4 = "0100007F"  # 127.0.0.1 as /proc/net/udp writes it
LOOPBACK_V6 = "00000000000000000000000001000000"  # ::1


def _socket_inodes(pid: int) -> set[str]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    return inodes


def _bound_addresses(pid: int) -> list[tuple[str, str]]:
    """``(protocol, local address)`` of every IP socket the process holds, from /proc/net."""
    inodes = _socket_inodes(pid)
    found = []
    for protocol in ("udp", "udp6", "tcp", "tcp6"):
        table = Path(f"/proc/{pid}/net/{protocol}")
        if not table.is_file():
            continue
        for line in table.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                found.append((protocol, fields[1].split(":")[0]))
    return found


@pytest.mark.skipif(not Path("/proc/self/net/udp").is_file(), reason="needs Linux /proc/net")
def test_a_running_node_binds_only_loopback_sockets_even_with_the_widening_variables_set(ros_domain_id: int) -> None:
    env = dict(os.environ)
    # What a user's shell may carry: the project's environment must remove it (DESIGN.md: it binds 0.0.0.0).
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env = loopback_environment(ros_domain_id, base=env)
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in env
    config = ROOT / "config"
    process = subprocess.Popen(
        [sys.executable, "-m", "robot_localization_suite.nodes.mcl_baseline", "--ros-args",
         "-p", f"map_yaml:={config / 'maps' / 'office.yaml'}", "-p", "max_particles:=1000", "-p", "min_particles:=100"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        addresses: list[tuple[str, str]] = []
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and process.poll() is None:
            addresses = _bound_addresses(process.pid)
            if len([a for a in addresses if a[0] == "udp"]) >= 3:  # discovery and user traffic are up
                time.sleep(1.0)
                addresses = _bound_addresses(process.pid)
                break
            time.sleep(0.5)
        assert process.poll() is None, "the node exited"
        assert len(addresses) >= 3, f"the node opened no DDS sockets within 60 s: {addresses}"
        outside = [(p, a) for p, a in addresses if a not in (LOOPBACK_V4, LOOPBACK_V6)]
        assert not outside, f"sockets beyond loopback: {outside}"
    finally:
        process.terminate()
        process.wait(timeout=30)
