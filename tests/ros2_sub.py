"""A ROS 2 subscriber of ``/joint_states`` that follows rmw_zenoh's conventions and is not
this project's: zenoh-ros2-sdk, given the message definitions (tests/data/ros2_msgs; it
cannot download them here). Run as a script:

    python tests/ros2_sub.py ROUTER_PORT DOMAIN OUT_FILE MAX_MESSAGES MAX_SECONDS

It writes ``ready`` and its type hash to OUT_FILE.ready once subscribed, then one JSON
line per message received (stamp, names, positions, velocities, efforts) to OUT_FILE,
and exits after MAX_MESSAGES or MAX_SECONDS, whichever comes first."""

from __future__ import annotations

import json
import math
import os
import sys
import threading
from pathlib import Path

MSGS = Path(__file__).resolve().parent / "data" / "ros2_msgs"
DEPS = ("builtin_interfaces/msg/Time", "std_msgs/msg/Header")
JOINT_STATE = "sensor_msgs/msg/JointState"


def definition(msgtype: str) -> str:
    pkg, kind, name = msgtype.split("/")
    return (MSGS / pkg / kind / f"{name}.msg").read_text()


def _num(x: float) -> float | None:
    return None if math.isnan(x) else float(x)


def main(port: int, domain: int, out: Path, most: int, seconds: float) -> int:
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.message_registry import get_registry
    from zenoh_ros2_sdk.session import ZenohSession

    get_registry(str(MSGS))  # dependencies of the type hash from these files only
    session = ZenohSession.get_instance("127.0.0.1", port)
    for dep in DEPS:
        session.register_message_type(definition(dep), dep)
    done = threading.Event()
    count = 0
    fh = out.open("a")

    def on_msg(msg: object) -> None:
        nonlocal count
        st = msg.header.stamp  # type: ignore[attr-defined]
        fh.write(json.dumps({
            "stamp_ns": st.sec * 1_000_000_000 + st.nanosec,
            "name": list(msg.name),  # type: ignore[attr-defined]
            "position": [_num(x) for x in msg.position],  # type: ignore[attr-defined]
            "velocity": [_num(x) for x in msg.velocity],  # type: ignore[attr-defined]
            "effort": [_num(x) for x in msg.effort]}) + "\n")  # type: ignore[attr-defined]
        fh.flush()
        count += 1
        if count >= most:
            done.set()

    sub = ROS2Subscriber(topic="/joint_states", msg_type=JOINT_STATE, callback=on_msg,
                         msg_definition=definition(JOINT_STATE), domain_id=domain,
                         router_port=port, node_name="ros2_sub_test")
    Path(f"{out}.ready").write_text(json.dumps({"type_hash": sub.type_hash,
                                                "keyexpr": sub.keyexpr}))
    done.wait(seconds)
    fh.close()
    os._exit(0)  # the SDK's session threads would hold the exit


if __name__ == "__main__":
    a = sys.argv[1:]
    sys.exit(main(int(a[0]), int(a[1]), Path(a[2]), int(a[3]), float(a[4])))
