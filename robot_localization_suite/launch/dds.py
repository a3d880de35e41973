"""Keep DDS on loopback: a Fast DDS profile that binds every socket to 127.0.0.1.

Tests, the demo and the runners load this profile through ``FASTRTPS_DEFAULT_PROFILES_FILE``:
UDPv4 whitelisted to 127.0.0.1 plus shared memory, no builtin transports, 127.0.0.1 as
metatraffic locator and initial peer. ``ROS_AUTOMATIC_DISCOVERY_RANGE`` and
``ROS_STATIC_PEERS`` are removed from the environment: with ``LOCALHOST`` on top of the
profile, rmw_fastrtps binds a UDP socket on 0.0.0.0 and one on the external interface
(checked with ``ss -uanp``; ../shared/DESIGN.md). README, "DDS on loopback", says how to
widen it deliberately for a robot network.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["LOOPBACK_PROFILE_XML", "loopback_profile_path", "loopback_environment", "use_loopback"]

LOOPBACK_PROFILE_XML = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>loopback_udp</transport_id>
      <type>UDPv4</type>
      <!-- Announce to 32 participants' ports, not Fast DDS's default 4: with more than 4 participants
           on the machine (a demo, a test run) two of the later ones would never discover each other. -->
      <maxInitialPeersRange>32</maxInitialPeersRange>
      <interfaceWhiteList>
        <address>127.0.0.1</address>
      </interfaceWhiteList>
    </transport_descriptor>
    <transport_descriptor>
      <transport_id>local_shm</transport_id>
      <type>SHM</type>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="loopback_participant" is_default_profile="true">
    <rtps>
      <userTransports>
        <transport_id>loopback_udp</transport_id>
        <transport_id>local_shm</transport_id>
      </userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
      <builtin>
        <metatrafficUnicastLocatorList>
          <locator>
            <udpv4>
              <address>127.0.0.1</address>
            </udpv4>
          </locator>
        </metatrafficUnicastLocatorList>
        <initialPeersList>
          <locator>
            <udpv4>
              <address>127.0.0.1</address>
            </udpv4>
          </locator>
        </initialPeersList>
      </builtin>
    </rtps>
  </participant>
</profiles>
"""


# Variables that make rmw_fastrtps open sockets beyond the profile's (see the module docstring).
_WIDENING = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")


def loopback_profile_path() -> Path:
    """Write the profile once per user into the temp directory and return its path."""
    path = Path(tempfile.gettempdir()) / f"rls_fastdds_loopback_{os.getuid()}.xml"
    if not path.is_file() or path.read_text() != LOOPBACK_PROFILE_XML:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(LOOPBACK_PROFILE_XML)
        tmp.replace(path)
    return path


def loopback_environment(domain_id: int | None = None, base: dict[str, str] | None = None) -> dict[str, str]:
    """An environment for ROS processes that keeps DDS on 127.0.0.1 (and on ``domain_id`` if given)."""
    env = dict(os.environ if base is None else base)
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(loopback_profile_path())
    env["FASTDDS_DEFAULT_PROFILES_FILE"] = env["FASTRTPS_DEFAULT_PROFILES_FILE"]
    for variable in _WIDENING:
        env.pop(variable, None)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    return env


def use_loopback(domain_id: int | None = None) -> None:
    """Put this process (and every process it starts) on loopback DDS, removing the widening variables."""
    env = loopback_environment(domain_id)
    for variable in _WIDENING:
        os.environ.pop(variable, None)
    os.environ.update(env)
