"""A Cyclone DDS configuration confined to this machine: 127.0.0.1, no multicast.

Used by the tests, the demo and the benchmarks, so that they never talk to other machines (or
other people's ROS 2 graphs) on the network. Cyclone DDS reads its configuration from the
``CYCLONEDDS_URI`` environment variable when a domain is first created in a process.
"""

from __future__ import annotations

import os
import random
import tempfile
from pathlib import Path

CONFIG = """<?xml version="1.0" encoding="UTF-8" ?>
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain Id="any">
    <General>
      <Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>
      <AllowMulticast>false</AllowMulticast>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>100</MaxAutoParticipantIndex>
      <Peers><Peer Address="127.0.0.1"/></Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
"""


def write_config(directory: str | Path | None = None) -> Path:
    """Write the loopback configuration to a file and return its path."""
    folder = Path(directory) if directory is not None else Path(tempfile.mkdtemp(prefix="neforward-dds-"))
    path = folder / "cyclonedds-loopback.xml"
    path.write_text(CONFIG)
    return path


def loopback_environment(domain_id: int | None = None, directory: str | Path | None = None) -> dict[str, str]:
    """Environment variables for a loopback-only process: CYCLONEDDS_URI and ROS_DOMAIN_ID.

    A random domain id in 100-199 is chosen when none is given, so that concurrent runs do not meet.
    """
    domain = random.randint(100, 199) if domain_id is None else domain_id
    return {"CYCLONEDDS_URI": write_config(directory).as_uri(), "ROS_DOMAIN_ID": str(domain)}


def use_loopback(domain_id: int | None = None) -> int:
    """Configure this process for loopback (before any participant is created); returns the domain id."""
    environment = loopback_environment(domain_id)
    os.environ.update(environment)
    return int(environment["ROS_DOMAIN_ID"])
