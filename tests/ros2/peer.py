#!/usr/bin/env python3
"""An independent ROS 2 peer for hapticctrl-ros2: Eclipse Cyclone DDS's Python
binding (no ROS installation), with ROS 2's topic names (rt/NAMESPACE/...) and
the standard message types defined here as IDL structs with ROS 2's DDS type
names (geometry_msgs::msg::dds_::PoseStamped_, ...), field for field as in
the Jazzy .msg files.

It subscribes to the node's pose, joint_states, wrench and status, publishes
target poses (geometry_msgs/PoseStamped on target_pose) from --target-after
seconds on, and after --duration seconds writes what it received:
  SUMMARY         key: value lines on stdout (counts, rates, latencies)
  --samples FILE  one line per pose sample with the joint sample and wrench of
                  the same stamp: "stamp_ns x y z qx qy qz qw fx fy fz q1..q6"
Discovery is unicast on 127.0.0.1 (CYCLONEDDS_URI set by the caller).
"""
import argparse
import gc
import sys
import threading
import time
from dataclasses import dataclass

from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64
    y: t.float64
    z: t.float64
    w: t.float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


@dataclass
class Wrench(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    force: Vector3
    torque: Vector3


@dataclass
class WrenchStamped(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    header: Header
    wrench: Wrench


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: t.sequence[str]
    position: t.sequence[t.float64]
    velocity: t.sequence[t.float64]
    effort: t.sequence[t.float64]


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: t.byte
    name: str
    message: str
    hardware_id: str
    values: t.sequence[KeyValue]


def stamp_ns(h):
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


class Recorder(Listener):
    """Takes every sample as it arrives (Cyclone's listener thread) and keeps
    (receive time, sample)."""

    def __init__(self):
        super().__init__()
        self.samples = []
        self.lock = threading.Lock()
        self.reader = None

    def on_data_available(self, reader):
        now = time.time_ns()
        got = reader.take(N=256)
        with self.lock:
            for s in got:
                self.samples.append((now, s))


def pct(values, p):
    if not values:
        return float("nan")
    v = sorted(values)
    return v[min(len(v) - 1, int(p / 100.0 * len(v)))]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, default=42)
    ap.add_argument("--namespace", default="/hapticctrl")
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--target", default="", help="X,Y,Z of the target pose to publish")
    ap.add_argument("--target-offset", default="",
                    help="DX,DY,DZ: the target is the first pose received plus this offset")
    ap.add_argument("--target-after", type=float, default=3.0)
    ap.add_argument("--target-rate", type=float, default=500.0)
    ap.add_argument("--frame-id", default="hapticctrl_base")
    ap.add_argument("--samples", default="")
    a = ap.parse_args()
    # The received samples are kept (tens of thousands of objects): the
    # collector's full passes over them would stall the listener for tens
    # of ms and show up as latency. Nothing here makes reference cycles.
    gc.disable()

    ns = a.namespace.strip("/")
    prefix = f"rt/{ns}/" if ns else "rt/"
    dp = DomainParticipant(a.domain)
    streaming = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(64),
                    Policy.Durability.Volatile)
    status_qos = Qos(Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)), Policy.History.KeepLast(1),
                     Policy.Durability.TransientLocal)
    setpoint_qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1),
                       Policy.Durability.Volatile,
                       Policy.DataRepresentation(use_cdrv0_representation=True))
    rec = {}
    readers = []
    for name, ty, qos in (("pose", PoseStamped, streaming), ("joint_states", JointState, streaming),
                          ("wrench", WrenchStamped, streaming), ("status", DiagnosticStatus, status_qos)):
        r = Recorder()
        rec[name] = r
        readers.append(DataReader(dp, Topic(dp, prefix + name, ty), qos=qos, listener=r))
    target_topic = Topic(dp, prefix + "target_pose", PoseStamped)
    writer = DataWriter(dp, target_topic, qos=setpoint_qos)

    target = None
    if a.target:
        target = [float(v) for v in a.target.split(",")]
        if len(target) != 3:
            sys.exit("--target X,Y,Z")
    offset = None
    if a.target_offset:
        offset = [float(v) for v in a.target_offset.split(",")]
        if len(offset) != 3:
            sys.exit("--target-offset DX,DY,DZ")
    t0 = time.monotonic()
    sent = 0
    first_target_ns = None
    period = 1.0 / a.target_rate
    next_send = t0 + a.target_after
    while time.monotonic() - t0 < a.duration:
        now = time.monotonic()
        if offset is not None and target is None and now >= next_send:
            with rec["pose"].lock:
                got = rec["pose"].samples[-1][1].pose.position if rec["pose"].samples else None
            if got is not None:
                target = [got.x + offset[0], got.y + offset[1], got.z + offset[2]]
        if target is not None and now >= next_send:
            ns_now = time.time_ns()
            if first_target_ns is None:
                first_target_ns = ns_now
            msg = PoseStamped(
                header=Header(stamp=Time(sec=ns_now // 1_000_000_000, nanosec=ns_now % 1_000_000_000),
                              frame_id=a.frame_id),
                pose=Pose(position=Point(x=target[0], y=target[1], z=target[2]),
                          orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)))
            writer.write(msg)
            sent += 1
            next_send += period
            if next_send < now:
                next_send = now + period
        time.sleep(max(0.0, min(period, next_send - time.monotonic())) if target is not None else 0.005)

    out = {}
    for name, r in rec.items():
        with r.lock:
            out[name] = list(r.samples)
    print(f"targets_sent: {sent}")
    if first_target_ns is not None:
        print(f"first_target_ns: {first_target_ns}")
        print("target: " + ",".join(f"{v:.6f}" for v in target))
    for name in ("pose", "joint_states", "wrench"):
        s = out[name]
        print(f"{name}.samples: {len(s)}")
        if len(s) >= 2:
            st = [stamp_ns(m.header) for _, m in s]
            span = (max(st) - min(st)) / 1e9
            print(f"{name}.rate_hz: {(len(s) - 1) / span if span > 0 else 0:.1f}")
            lat = [(rt - stamp_ns(m.header)) / 1e3 for rt, m in s]
            print(f"{name}.latency_us_p50: {pct(lat, 50):.1f}")
            print(f"{name}.latency_us_p99: {pct(lat, 99):.1f}")
            print(f"{name}.latency_us_max: {max(lat):.1f}")
            print(f"{name}.stamps_increasing: {int(all(b > a_ for a_, b in zip(st, st[1:])))}")
            print(f"{name}.frame_id: {s[-1][1].header.frame_id}")
    st = out["status"]
    print(f"status.samples: {len(st)}")
    if st:
        last = st[-1][1]
        print(f"status.level: {last.level}")
        print(f"status.message: {last.message}")
        for kv in last.values:
            print(f"status.{kv.key}: {kv.value}")
    js = out["joint_states"]
    if js:
        print(f"joint_states.names: {','.join(js[-1][1].name)}")
    if a.samples:
        joints = {stamp_ns(m.header): m for _, m in js}
        wrenches = {stamp_ns(m.header): m for _, m in out["wrench"]}
        with open(a.samples, "w") as f:
            for _, m in out["pose"]:
                k = stamp_ns(m.header)
                j = joints.get(k)
                w = wrenches.get(k)
                if j is None or w is None or len(j.position) != 6:
                    continue
                p = m.pose
                vals = [p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                        p.orientation.z, p.orientation.w, w.wrench.force.x, w.wrench.force.y,
                        w.wrench.force.z] + list(j.position)
                f.write(f"{k} " + " ".join(repr(v) for v in vals) + "\n")


if __name__ == "__main__":
    main()
