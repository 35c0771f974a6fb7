"""ROS bags written with rosbags' own writers, for the importer tests and the formats guide's example.

An actuator record as a ros2_control bench would log it: ``/joint_states`` (sensor_msgs/JointState,
joints ``base`` and ``axis``, header stamps) at the loop rate, ``/effort_cmd`` (std_msgs/Float64, no
header: the bag's receive time) at the loop rate, ``/ft`` (geometry_msgs/WrenchStamped) from a slower
force sensor, and ``/debug`` (std_msgs/Float64MultiArray)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

T0_NS = 1_700_000_000 * 1_000_000_000  # the bag's clock: ns since the Unix epoch


def write_bag(path: Path, storage: str, t: np.ndarray, pos: np.ndarray, vel: np.ndarray, effort_cmd: np.ndarray,
              t_ft: np.ndarray, force: np.ndarray, *, flip_joint_order_at: int | None = None) -> Path:
    """Write the bag (``storage``: ``sqlite3`` or ``mcap`` for ROS 2, ``ros1`` for a ROS 1 .bag) and
    return its path. Times ``t``/``t_ft`` [s] from 0; stamps are ``T0_NS + round(t * 1e9)``."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = storage == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Vec = T["geometry_msgs/msg/Vector3"]

    def header(ns: int) -> Any:
        stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        return Header(seq=0, stamp=stamp, frame_id="base") if ros1 else Header(stamp=stamp, frame_id="base")

    def js(k: int, ns: int) -> Any:
        names = ["base", "axis"]
        p, v, e = [0.5, pos[k]], [0.0, vel[k]], [0.0, effort_cmd[k]]
        if flip_joint_order_at is not None and k >= flip_joint_order_at:
            names, p, v, e = names[::-1], p[::-1], v[::-1], e[::-1]
        return T["sensor_msgs/msg/JointState"](header=header(ns), name=names, position=np.array(p),
                                               velocity=np.array(v), effort=np.array(e))

    def wrench(k: int, ns: int) -> Any:
        return T["geometry_msgs/msg/WrenchStamped"](header=header(ns), wrench=T["geometry_msgs/msg/Wrench"](
            force=Vec(x=0.0, y=0.0, z=force[k]), torque=Vec(x=0.0, y=0.0, z=0.1 * force[k])))

    def f64(k: int, ns: int) -> Any:
        return T["std_msgs/msg/Float64"](data=effort_cmd[k])

    def arr(k: int, ns: int) -> Any:
        layout = T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
        return T["std_msgs/msg/Float64MultiArray"](layout=layout, data=np.array([pos[k], vel[k], 1.0]))

    topics = [("/joint_states", "sensor_msgs/msg/JointState", t, js), ("/effort_cmd", "std_msgs/msg/Float64", t, f64),
              ("/ft", "geometry_msgs/msg/WrenchStamped", t_ft, wrench),
              ("/debug", "std_msgs/msg/Float64MultiArray", t, arr)]
    events = sorted((T0_NS + round(tt * 1e9), i, k) for i, (_, _, times, _) in enumerate(topics)
                    for k, tt in enumerate(times))
    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        out = path.with_suffix(".bag")
        with Writer1(out) as w:
            conns = [w.add_connection(tp, mt, typestore=ts) for tp, mt, _, _ in topics]
            for ns, i, k in events:
                w.write(conns[i], ns, ts.serialize_ros1(topics[i][3](k, ns), topics[i][1]))
        return out
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = [w.add_connection(tp, mt, typestore=ts) for tp, mt, _, _ in topics]
        for ns, i, k in events:
            w.write(conns[i], ns, ts.serialize_cdr(topics[i][3](k, ns), topics[i][1]))
    return path
