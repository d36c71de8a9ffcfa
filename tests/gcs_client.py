"""A ground station for tests/gcs.rs: pymavlink against `uquad sim --realtime`.

Protocol with the Rust test: this script binds a UDP port and prints `port N`; the test starts
uquad sending there, then writes `started` (uquad was just spawned) and `run DIR` (its run
folder) on stdin. The script flies a scenario, prints one JSON line of what it measured and
exits 0; on a failed expectation it prints why and exits 1.

Scenarios:
  fly PARAM_COUNT  heartbeat, health before arming, parameters, FTP, a refused arm, arm,
                   takeoff to 1.5 m, mode requests as the common clients send them, return,
                   land.
  link-loss        arm, takeoff, noise and a flood, then silence: the vehicle must land.
  mission          a refused upload, an upload, its download, arm, the Mission mode asked
                   for: the items reached in order, MISSION_CURRENT following them, landed.
  flights N        N flights in one run: arm, takeoff to 1 m, land, each time.
  land-param       arm, takeoff to 2 m, CMD_LAND_M_S set to 0.3 in the air, land.
  calibrate        a preflight calibration (gyro) once the estimate runs: accepted, the arm
                   waits for the new one; in the air: denied, named.
  guided           arm, takeoff to 1.5 m, a position target 3 m north streamed for 2 s
                   (as a companion computer sends it), reached and held, land.
  download MAX     one flight, then the run's log downloaded (at most MAX bytes of it,
                   0: whole) while telemetry goes on; pyulog reads a whole one.
  download-pty MAX the same over a pty standing in for a serial radio (prints `pty PATH`
                   instead of `port N`).
"""

import json
import math
import os
import random
import select
import socket
import struct
import sys
import time
import tty

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

mav = mavutil.mavlink
LONG = 30.0


def fail(why):
    print(f"FAIL: {why}", flush=True)
    sys.exit(1)


class PtyLink(mavutil.mavfile):
    """pymavlink over a pty's master side: the vehicle opens the other side as its radio."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        self.name = os.ttyname(self.slave)
        mavutil.mavfile.__init__(
            self, self.master, self.name, source_system=255, source_component=190
        )

    def recv(self, n=None):
        r, _, _ = select.select([self.master], [], [], 0.05)
        if not r:
            return b""
        try:
            return os.read(self.master, 4096)
        except OSError:
            return b""

    def write(self, buf):
        try:
            os.write(self.master, buf)
        except OSError:
            pass


class Station:
    def __init__(self, pty=False):
        if pty:
            self.conn = PtyLink()
            self.port = None
        else:
            self.conn = mavutil.mavlink_connection(
                "udpin:127.0.0.1:0", source_system=255, source_component=190
            )
            self.port = self.conn.port.getsockname()[1]
        self.beating = True
        self.heard = False
        self.last_beat = 0.0
        self.texts = []
        self.chunks = {}
        self.last = {}

    def pump(self, timeout=0.1):
        """One message (or None), sending our heartbeat each second while beating."""
        now = time.time()
        if self.beating and now - self.last_beat >= 1.0:
            self.last_beat = now
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        msg = self.conn.recv_match(blocking=True, timeout=timeout)
        if msg is None:
            return None
        if self.beating and not self.heard:
            # A heartbeat sent before the vehicle was heard went nowhere (udpin knows no peer
            # yet): announce ourselves as a ground station at once, or our first commands
            # come from a stranger.
            self.heard = True
            self.last_beat = time.time()
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        kind = msg.get_type()
        self.last[kind] = msg
        if kind == "STATUSTEXT":
            self.statustext(msg)
        return msg

    def statustext(self, msg):
        """Texts, long ones put together from their 50-byte chunks (same id)."""
        if msg.id == 0:
            self.texts.append(msg.text)
            return
        parts = self.chunks.setdefault(msg.id, {})
        parts[msg.chunk_seq] = msg.text
        if len(msg.text.encode()) < 50:
            self.texts.append("".join(parts[i] for i in sorted(parts)))
            del self.chunks[msg.id]

    def wait(self, what, test, timeout=LONG):
        end = time.time() + timeout
        while time.time() < end:
            msg = self.pump()
            if msg is not None and test(msg):
                return msg
        fail(f"no {what} within {timeout} s; texts so far: {self.texts}")

    def wait_text(self, part, timeout=LONG):
        """Waits for a text containing `part` (one already received counts: a refusal's text
        comes before its COMMAND_ACK)."""
        end = time.time() + timeout
        while time.time() < end:
            if any(part in t for t in self.texts):
                return
            self.pump()
        fail(f"no STATUSTEXT containing {part!r}; texts: {self.texts}")

    def command(self, cmd, p, result=mav.MAV_RESULT_ACCEPTED):
        self.conn.mav.command_long_send(1, 1, cmd, 0, *p)
        ack = self.wait(
            f"COMMAND_ACK of {cmd}",
            lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd,
        )
        if ack.result != result:
            fail(f"command {cmd}: result {ack.result}, expected {result}; texts: {self.texts}")

    def param(self, pid, timeout=LONG):
        return self.wait(
            f"PARAM_VALUE {pid}",
            lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == pid,
            timeout,
        )


def px4_mode(main, sub):
    """A custom mode packed as PX4 packs it: main mode in bits 16-23, sub mode in 24-31."""
    return (sub << 24) | (main << 16)


# uquad's modes as HEARTBEAT tells them (PX4's AUTO sub modes): on the ground and in a hold
# it is AUTO LOITER ("Hold"), told apart by the armed flag and the landed state.
AUTO = 4
LOITER, MISSION_SUB, RTL, LAND_SUB = 3, 4, 5, 6
HOLD = px4_mode(AUTO, LOITER)
DISARMED = HOLD
RETURN = px4_mode(AUTO, RTL)
LANDING = px4_mode(AUTO, LAND_SUB)


def mode_is(custom):
    return lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == custom


def holding_in_air(s):
    """A heartbeat in hold, armed, and the landed state in the air."""
    def test(m):
        ext = s.last.get("EXTENDED_SYS_STATE")
        return (
            m.get_type() == "HEARTBEAT"
            and m.custom_mode == HOLD
            and m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
            and ext is not None
            and ext.landed_state == mav.MAV_LANDED_STATE_IN_AIR
        )

    return test


def send_arm(s):
    """Asks to arm once; its COMMAND_ACK."""
    s.conn.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    return s.wait(
        "COMMAND_ACK of arm",
        lambda m: m.get_type() == "COMMAND_ACK"
        and m.command == mav.MAV_CMD_COMPONENT_ARM_DISARM,
    )


def arm(s):
    """Arms, trying again while the IMU has not settled (as an operator would)."""
    end = time.time() + LONG
    while time.time() < end:
        ack = send_arm(s)
        if ack.result == mav.MAV_RESULT_ACCEPTED:
            return
        refusals = [t for t in s.texts if t.startswith("arm refused")]
        # Settling, or (calibrated before arming) the estimate not ready yet.
        waiting = ("arm refused: imu:", "arm refused: estimator:")
        if not refusals or not refusals[-1].startswith(waiting):
            fail(f"arm refused: {s.texts}")
        time.sleep(0.5)
    fail("never armed")


def after_ramp(s, cmd, p):
    """Sends `cmd`, again while the ESCs' start-up ramp runs (armed under an estimate that ran
    before arming, the ramp follows the arm), until it is accepted."""
    until_taken(s, cmd, p, ["start-up ramp is not done"])


def take_off(s, height_m):
    after_ramp(s, mav.MAV_CMD_NAV_TAKEOFF, [0, 0, 0, 0, 0, 0, height_m])


def arm_and_take_off(s, height_m):
    arm(s)
    # The estimate exists once the IMU calibration is done (after arming, in the original's
    # order).
    s.wait("ATTITUDE", lambda m: m.get_type() == "ATTITUDE")
    take_off(s, height_m)
    s.wait("hold after the takeoff", holding_in_air(s))


def before_arm(s):
    """imu.calibrate = "before-arm": an arm during the calibration is refused naming the
    estimator; attitude and position arrive while disarmed; the arm is taken once the estimate
    is ready; the flight goes on as usual."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    refusal, end = None, time.time() + LONG
    while refusal is None and time.time() < end:
        ack = send_arm(s)
        if ack.result == mav.MAV_RESULT_ACCEPTED:
            fail(f"armed during the calibration: {s.texts}")
        refusals = [t for t in s.texts if t.startswith("arm refused")]
        if refusals and refusals[-1].startswith("arm refused: estimator:"):
            refusal = refusals[-1]
        elif not refusals or not refusals[-1].startswith("arm refused: imu:"):
            fail(f"arm refused: {s.texts}")
        time.sleep(0.2)
    if refusal is None:
        fail(f"no refusal naming the estimator: {s.texts}")

    def disarmed():
        hb = s.last.get("HEARTBEAT")
        return hb is not None and not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED

    att = s.wait("ATTITUDE", lambda m: m.get_type() == "ATTITUDE")
    att_disarmed = disarmed()
    pos = s.wait(
        "GLOBAL_POSITION_INT",
        lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.lat != 0,
    )
    pos_disarmed = disarmed()
    arm_and_take_off(s, 1.0)
    land(s)
    return {
        "refusal": refusal,
        "attitude_boot_ms": att.time_boot_ms,
        "attitude_disarmed": att_disarmed,
        "position_boot_ms": pos.time_boot_ms,
        "position_disarmed": pos_disarmed,
    }


def altitude_errors(s, height_m, seconds):
    """Largest |relative altitude − height| over `seconds` of GLOBAL_POSITION_INT."""
    worst, n, end = 0.0, 0, time.time() + seconds
    while time.time() < end:
        m = s.pump()
        if m is not None and m.get_type() == "GLOBAL_POSITION_INT":
            worst = max(worst, abs(m.relative_alt / 1000.0 - height_m))
            n += 1
    if n == 0:
        fail("no GLOBAL_POSITION_INT while hovering")
    return worst, n


def landed_and_disarmed(s):
    """Both reported: the landed state on the ground, and a heartbeat disarmed."""
    def both(_):
        hb, ext = s.last.get("HEARTBEAT"), s.last.get("EXTENDED_SYS_STATE")
        return (
            hb is not None
            and ext is not None
            and hb.custom_mode == DISARMED
            and not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
            and ext.landed_state == mav.MAV_LANDED_STATE_ON_GROUND
        )

    # Both may have come already (inside a caller's own loop), and a simulator that ends
    # at the touchdown sends nothing after them: judged on what was heard, then waited for.
    if not both(None):
        s.wait("the landed state and a disarmed heartbeat", both)


def land(s):
    s.command(mav.MAV_CMD_NAV_LAND, [0] * 7)
    landed_and_disarmed(s)


def parameters(s, expected):
    s.conn.mav.param_request_list_send(1, 1)
    ids, count = set(), None
    end = time.time() + LONG
    while time.time() < end and (count is None or len(ids) < count):
        m = s.pump()
        if m is not None and m.get_type() == "PARAM_VALUE":
            ids.add(m.param_id)
            count = m.param_count
    if count != expected or len(ids) != expected:
        fail(f"{len(ids)} parameters of {count} listed, {expected} mapped")
    s.conn.mav.param_set_send(1, 1, b"CMD_CLIMB_M_S", 0.4, mav.MAV_PARAM_TYPE_REAL32)
    if abs(s.param("CMD_CLIMB_M_S").param_value - 0.4) > 1e-6:
        fail("the set value did not come back")
    s.conn.mav.param_request_read_send(1, 1, b"CMD_CLIMB_M_S", -1)
    if abs(s.param("CMD_CLIMB_M_S").param_value - 0.4) > 1e-6:
        fail("the set value did not read back")
    # A value the configuration's rules refuse: the old one comes back, and why.
    s.conn.mav.param_set_send(1, 1, b"WD_MISSED_ACKS", 50, mav.MAV_PARAM_TYPE_INT32)
    if s.param("WD_MISSED_ACKS").param_value != 3:
        fail("a refused set changed the value")
    s.wait_text("WD_MISSED_ACKS not set: watchdog.max_missed_acks: 50 is out of range")
    # An integer: announced REAL32 (what every encoding reads the same), and set in either
    # encoding a client may use for INT32: its bytes (PX4's), or the number (ArduPilot's).
    s.conn.mav.param_request_read_send(1, 1, b"WD_MISSED_ACKS", -1)
    if s.param("WD_MISSED_ACKS").param_type != mav.MAV_PARAM_TYPE_REAL32:
        fail("an integer parameter is not announced as REAL32")
    bytewise = struct.unpack("<f", struct.pack("<i", 4))[0]
    s.conn.mav.param_set_send(1, 1, b"WD_MISSED_ACKS", bytewise, mav.MAV_PARAM_TYPE_INT32)
    if s.param("WD_MISSED_ACKS").param_value != 4:
        fail("a bytewise INT32 set did not read as 4")
    s.conn.mav.param_set_send(1, 1, b"WD_MISSED_ACKS", 3, mav.MAV_PARAM_TYPE_INT32)
    if s.param("WD_MISSED_ACKS").param_value != 3:
        fail("a C-cast INT32 set did not read as 3")
    return len(ids)


def logging_healthy(s, healthy):
    """Waits until SYS_STATUS says the run folder can (or cannot) be written."""
    bit = mav.MAV_SYS_STATUS_LOGGING

    def says(m):
        return (
            m.get_type() == "SYS_STATUS"
            and m.onboard_control_sensors_present & bit
            and bool(m.onboard_control_sensors_health & bit) == healthy
        )

    s.wait(f"SYS_STATUS logging {'healthy' if healthy else 'failing'}", says)


def refused_arm(s, run_dir):
    """The run folder replaced by a file (a card pulled): arming is refused, and says why."""
    moved = run_dir + ".moved"
    os.rename(run_dir, moved)
    with open(run_dir, "w") as f:
        f.write("not a folder")
    logging_healthy(s, False)
    # The IMU's check comes first: until it has settled, that is the refusal.
    end = time.time() + LONG
    while not any(t.startswith("arm refused: log: cannot write in") for t in s.texts):
        if time.time() > end:
            fail(f"arm never refused for the log folder; texts: {s.texts}")
        s.command(
            mav.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0, 0, 0, 0, 0, 0], mav.MAV_RESULT_DENIED
        )
        s.pump(0.5)
    os.remove(run_dir)
    os.rename(moved, run_dir)
    logging_healthy(s, True)


def attitude_interval_ms(s, seconds):
    """The median interval between ATTITUDE messages on the vehicle's own clock (what a
    stall of this machine cannot shift), ms."""
    stamps, end = [], time.time() + seconds
    while time.time() < end:
        m = s.pump()
        if m is not None and m.get_type() == "ATTITUDE":
            stamps.append(m.time_boot_ms)
    gaps = sorted(b - a for a, b in zip(stamps, stamps[1:]))
    if not gaps:
        fail("no ATTITUDE to time")
    return gaps[len(gaps) // 2]


def requests(s):
    """AUTOPILOT_VERSION on request; ATTITUDE's interval changed from 100 ms to 40 ms."""
    s.last.pop("AUTOPILOT_VERSION", None)
    # The message comes before the command's COMMAND_ACK.
    s.command(mav.MAV_CMD_REQUEST_MESSAGE, [148, 0, 0, 0, 0, 0, 0])
    s.wait("AUTOPILOT_VERSION", lambda _: "AUTOPILOT_VERSION" in s.last)
    default_ms = attitude_interval_ms(s, 1.0)
    s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, [30, 40_000, 0, 0, 0, 0, 0])
    s.pump()
    asked_ms = attitude_interval_ms(s, 2.0)
    s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, [30, 0, 0, 0, 0, 0, 0])
    if not (90 <= default_ms <= 110 and 30 <= asked_ms <= 50):
        fail(f"ATTITUDE every {default_ms} ms, then {asked_ms} ms after asking for 40 ms")
    return default_ms, asked_ms


def stranger_denied(s):
    """Another system announcing itself as a quadrotor is no ground station: its ARM and
    its parameter set are not obeyed (the ARM answered DENIED)."""
    # The vehicle's address: the one our udpin connection has heard from.
    host, port = next(iter(s.conn.clients))
    x = mavutil.mavlink_connection(
        f"udpout:{host}:{port}", source_system=42, source_component=1
    )
    x.mav.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0, 0)
    x.mav.param_set_send(1, 1, b"CMD_CLIMB_M_S", 0.3, mav.MAV_PARAM_TYPE_REAL32)
    x.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    deadline = time.time() + LONG
    while time.time() < deadline:
        s.pump(0.01)
        m = x.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
        if m is not None and m.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if m.result != mav.MAV_RESULT_DENIED:
                fail(f"a stranger's ARM: result {m.result}")
            x.close()
            return
    fail("no COMMAND_ACK to a stranger's ARM")


def stalled(s, started):
    """The IMU falls silent 1 s into the run: an ARM sent at 3 s is answered DENIED once
    commander.input_expiry_s (1 s) has passed, not FAILED after the link's 5 s, and is never
    applied later."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    while time.time() < started + 3.0:
        s.pump()
    sent = time.time()
    s.conn.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    ack = s.wait(
        "COMMAND_ACK of arm",
        lambda m: m.get_type() == "COMMAND_ACK"
        and m.command == mav.MAV_CMD_COMPONENT_ARM_DISARM,
    )
    answered_s = time.time() - sent
    if ack.result != mav.MAV_RESULT_DENIED:
        fail(f"arm with the IMU silent: result {ack.result}, expected DENIED; texts: {s.texts}")
    end = time.time() + 3.0
    while time.time() < end:
        m = s.pump()
        if m is not None and m.get_type() == "HEARTBEAT" and (
            m.custom_mode != DISARMED or m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
        ):
            fail(f"armed after the refusal: {m}")
    return {"arm_answered_s": round(answered_s, 2)}


SIGNING_PASSPHRASE = b"uquad test passphrase"


def signed(s):
    """gcs.signing_key_file set: a station signing with the key arms and disarms; another
    that does not sign, and one signing with another key, are not heard (no COMMAND_ACK)."""
    import hashlib

    key = hashlib.sha256(SIGNING_PASSPHRASE).digest()
    s.conn.setup_signing(key, sign_outgoing=True)
    s.wait("a signed heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    host, port = next(iter(s.conn.clients))
    unheard = {}
    for name, other_key in (("unsigned", None), ("other key", hashlib.sha256(b"x").digest())):
        x = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=200, source_component=190)
        if other_key is not None:
            x.setup_signing(other_key, sign_outgoing=True)
        x.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        x.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        end = time.time() + 2.0
        while time.time() < end:
            s.pump(0.01)
            m = x.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
            if m is not None:
                fail(f"a station with {name} was answered: {m}")
        unheard[name] = True
        x.close()
    arm(s)
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, [0, 0, 0, 0, 0, 0, 0])
    return {"unheard": unheard}


def ftp(s):
    """MAVLink FTP as a ground station opens it (the parameter file first): answered at once
    with a NAK, file not found (no file is served yet); the time to the answer, ms."""
    payload = bytearray(251)
    struct.pack_into("<HBBBBBBI", payload, 0, 7, 0, 4, 16, 0, 0, 0, 0)
    payload[12:28] = b"@PARAM/param.pck"
    t0 = time.time()
    s.conn.mav.file_transfer_protocol_send(0, 1, 1, payload)
    m = s.wait("an FTP answer", lambda m: m.get_type() == "FILE_TRANSFER_PROTOCOL")
    answer_ms = (time.time() - t0) * 1000.0
    seq, _, opcode, size, req_opcode = struct.unpack_from("<HBBBB", bytes(m.payload), 0)
    if (seq, opcode, size, req_opcode, m.payload[12]) != (8, 129, 1, 4, 10):
        fail(f"FTP open answered {list(m.payload[:13])}")
    return round(answer_ms, 1)


def set_mode_as_qgc(s, custom, what):
    """SET_MODE with a packed custom mode, as QGroundControl sends it: accepted."""
    s.conn.mav.set_mode_send(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom)
    ack = s.wait(
        "COMMAND_ACK of SET_MODE",
        lambda m: m.get_type() == "COMMAND_ACK" and m.command == mav.MAV_CMD_DO_SET_MODE,
    )
    if ack.result != mav.MAV_RESULT_ACCEPTED:
        fail(f"SET_MODE {what}: result {ack.result}; texts: {s.texts}")


def mode_requests(s):
    """In the air, in hold: hold asked for as each common client asks (QGroundControl's
    SET_MODE with the packed custom mode; MAVSDK's DO_SET_MODE, base 1|128, main, sub; a
    COMMAND_INT), a mode uquad lacks (PX4's acro mode) refused with its name, the
    standard modes listed; the mode names pymavlink shows so far."""
    names = [mavutil.mode_string_v10(s.last["HEARTBEAT"])]
    set_mode_as_qgc(s, HOLD, "hold (QGroundControl's)")
    s.command(mav.MAV_CMD_DO_SET_MODE, [129, AUTO, LOITER, 0, 0, 0, 0])
    s.conn.mav.command_int_send(
        1, 1, mav.MAV_FRAME_GLOBAL, mav.MAV_CMD_DO_SET_MODE, 0, 0,
        mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, AUTO, LOITER, 0, 0, 0, 0,
    )
    ack = s.wait(
        "COMMAND_ACK of DO_SET_MODE",
        lambda m: m.get_type() == "COMMAND_ACK" and m.command == mav.MAV_CMD_DO_SET_MODE,
    )
    if ack.result != mav.MAV_RESULT_ACCEPTED:
        fail(f"DO_SET_MODE hold by COMMAND_INT: result {ack.result}; texts: {s.texts}")
    s.wait_text("mode hold: command hold")
    s.command(mav.MAV_CMD_DO_SET_MODE, [1, 5, 0, 0, 0, 0, 0], mav.MAV_RESULT_DENIED)
    s.wait_text("uquad has no acro")
    s.conn.mav.command_long_send(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, 435, 0, 0, 0, 0, 0, 0)
    listed = {}
    end = time.time() + LONG
    while len(listed) < 8 and time.time() < end:
        m = s.pump()
        if m is not None and m.get_type() == "AVAILABLE_MODES":
            listed[m.mode_index] = (m.mode_name, m.properties, m.number_modes)
    selectable = sorted(
        n for n, p, _ in listed.values() if not p & mav.MAV_MODE_PROPERTY_NOT_USER_SELECTABLE
    )
    wanted = ["Altitude", "Hold", "Land", "Mission", "Position", "Return", "Takeoff"]
    if selectable != wanted or len(listed) != 8:
        fail(f"AVAILABLE_MODES: {listed}")
    current = s.wait("CURRENT_MODE", lambda m: m.get_type() == "CURRENT_MODE")
    if current.custom_mode != HOLD:
        fail(f"CURRENT_MODE {current}")
    return names


def health_times(s, started):
    """Seconds from the start until a ground station sees, before arming: a global position,
    the home position, and SYS_STATUS's pre-arm bit healthy (what a client waits for before
    it lets its user arm)."""
    bit = mav.MAV_SYS_STATUS_PREARM_CHECK
    seen = {}
    end = time.time() + LONG
    while len(seen) < 3 and time.time() < end:
        m = s.pump()
        if m is None:
            continue
        kind, t = m.get_type(), round(time.time() - started, 2)
        if kind == "GLOBAL_POSITION_INT" and m.lat != 0:
            seen.setdefault("position_s", t)
        elif kind == "HOME_POSITION" and m.latitude != 0:
            seen.setdefault("home_s", t)
        elif (
            kind == "SYS_STATUS"
            and m.onboard_control_sensors_present & bit
            and m.onboard_control_sensors_health & bit
        ):
            seen.setdefault("prearm_s", t)
    if len(seen) < 3:
        fail(f"before arming, only {seen} within {LONG} s")
    return seen


def fly(s, run_dir, started, expected):
    hb = s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    heartbeat_s = time.time() - started
    if (
        hb.type != mav.MAV_TYPE_QUADROTOR
        or hb.autopilot != mav.MAV_AUTOPILOT_PX4
        or hb.custom_mode != DISARMED
    ):
        fail(f"first heartbeat {hb}")
    health = health_times(s, started)
    n = parameters(s, expected)
    ftp_ms = ftp(s)
    stranger_denied(s)
    refused_arm(s, run_dir)
    arm_and_take_off(s, 1.5)
    alt_err, samples = altitude_errors(s, 1.5, 5.0)
    if alt_err > 0.2:
        fail(f"altitude {alt_err:.3f} m from 1.5 m while holding")
    attitude_ms = requests(s)
    names = mode_requests(s)
    load = s.last["SYS_STATUS"].load
    s.conn.mav.param_set_send(1, 1, b"CMD_CRASH_TILT", 0.9, mav.MAV_PARAM_TYPE_REAL32)
    s.wait_text(
        "CMD_CRASH_TILT not set: commander.crash_tilt_rad: flight-critical, refused while hold"
    )
    # Return, then land, each as pymavlink's PX4 map and MAVSDK encode it.
    s.command(mav.MAV_CMD_DO_SET_MODE, [29, AUTO, RTL, 0, 0, 0, 0])
    s.wait("the return in the heartbeat", mode_is(RETURN))
    names.append(mavutil.mode_string_v10(s.last["HEARTBEAT"]))
    s.command(mav.MAV_CMD_DO_SET_MODE, [129, AUTO, LAND_SUB, 0, 0, 0, 0])
    s.wait("the landing in the heartbeat", mode_is(LANDING))
    names.append(mavutil.mode_string_v10(s.last["HEARTBEAT"]))
    landed_and_disarmed(s)
    return {
        "before_arming": health,
        "mode_names": names,
        "heartbeat_s": round(heartbeat_s, 3),
        "params": n,
        "ftp_answer_ms": ftp_ms,
        "alt_err_max_m": round(alt_err, 3),
        "alt_samples": samples,
        "attitude_interval_ms_default_then_asked_40": attitude_ms,
        "control_load_permille": load,
    }


def noise(s):
    """Garbage, cut and wrong-CRC frames, unknown ids, and a flood of valid ones."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    to = next(iter(s.conn.clients))  # the vehicle's address, as pymavlink learnt it
    hb = s.conn.mav.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    good = hb.pack(s.conn.mav)
    # The flood: valid frames the link takes and ignores (heartbeats are never dropped for
    # the rate, so they would not test it).
    flood_frame = s.conn.mav.timesync_encode(0, 1).pack(s.conn.mav)
    rng = random.Random(7)
    for _ in range(50):
        sock.sendto(bytes(rng.randrange(256) for _ in range(64)), to)
        sock.sendto(good[:7], to)
        sock.sendto(good[:-1] + bytes([good[-1] ^ 0xFF]), to)
        sock.sendto(b"\xfd\x01\x00\x00\x00\xff\xbe\x77\x77\x77\x00\x00\x00", to)
        # Paced: the kernel's buffer must not drop what is meant to be counted.
        s.pump(0.01)
    # Ten times the vehicle's own telemetry (~45 frames/s): 45 frames every 0.1 s for 3 s,
    # more than twice the link's budget (gcs.max_rx_per_s = 200).
    flood = 0
    for _ in range(30):
        for _ in range(45):
            sock.sendto(flood_frame, to)
            flood += 1
        slot_end = time.time() + 0.1
        while time.time() < slot_end:
            s.pump(max(0.0, slot_end - time.time()))
    return flood


def link_loss(s, started):
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    arm_and_take_off(s, 1.0)
    flood = noise(s)
    s.beating = False
    silent_at = time.time()
    s.wait_text("failsafe link-loss: land")
    landing_s = time.time() - silent_at
    landed_and_disarmed(s)
    return {"flood_frames": flood, "failsafe_after_s": round(landing_s, 2)}


def upload(s, items):
    """Uploads MISSION_ITEM_INTs as a ground station does; returns the MISSION_ACK."""
    s.conn.mav.mission_count_send(1, 1, len(items), mav.MAV_MISSION_TYPE_MISSION)
    end = time.time() + LONG
    while time.time() < end:
        m = s.pump()
        if m is None:
            continue
        kind = m.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            s.conn.mav.send(items[m.seq])
        elif kind == "MISSION_ACK":
            return m
    fail("no MISSION_ACK of the upload")


def download(s):
    """The vehicle's mission, item by item."""
    s.conn.mav.mission_request_list_send(1, 1, mav.MAV_MISSION_TYPE_MISSION)
    count = s.wait("MISSION_COUNT", lambda m: m.get_type() == "MISSION_COUNT").count
    items = []
    for seq in range(count):
        s.conn.mav.mission_request_int_send(1, 1, seq, mav.MAV_MISSION_TYPE_MISSION)
        items.append(
            s.wait(
                f"MISSION_ITEM_INT {seq}",
                lambda m, seq=seq: m.get_type() == "MISSION_ITEM_INT" and m.seq == seq,
            )
        )
    s.conn.mav.mission_ack_send(1, 1, mav.MAV_MISSION_ACCEPTED, mav.MAV_MISSION_TYPE_MISSION)
    return items


def mission_items(s, lat, lon):
    """Take off to 1.5 m, 4 m north, half a turn of radius 2 m clockwise around a point 2 m
    east of there, back, land: in latitude and longitude, as ground stations send them."""
    north = 1.0 / 111_195.0  # degrees of latitude per metre (the vehicle's sphere)
    east = north / math.cos(math.radians(lat))
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT

    def item(seq, cmd, p1=0, p3=0, n_m=None, e_m=0.0, z=1.5, frame=rel):
        x = y = 0
        if n_m is not None:
            x, y = round((lat + n_m * north) * 1e7), round((lon + e_m * east) * 1e7)
        return s.conn.mav.mission_item_int_encode(
            1, 1, seq, frame, cmd, int(seq == 0), 1, p1, 0, p3, 0, x, y, z,
            mav.MAV_MISSION_TYPE_MISSION,
        )

    return [
        item(0, mav.MAV_CMD_NAV_TAKEOFF),
        item(1, mav.MAV_CMD_NAV_WAYPOINT, n_m=4.0),
        item(2, mav.MAV_CMD_NAV_LOITER_TURNS, p1=0.5, p3=2.0, n_m=4.0, e_m=2.0),
        item(3, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=mav.MAV_FRAME_MISSION, z=0),
        item(4, mav.MAV_CMD_NAV_LAND, frame=mav.MAV_FRAME_MISSION, z=0),
    ]


def mission(s):
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    fix = s.wait("a 3-D fix", lambda m: m.get_type() == "GPS_RAW_INT" and m.fix_type >= 3)
    lat, lon = fix.lat / 1e7, fix.lon / 1e7
    items = mission_items(s, lat, lon)
    # A waypoint 500 m away: outside the fence, refused with the loader's words.
    far = mission_items(s, lat + 500 / 111_195.0, lon)
    far[0] = items[0]
    ack = upload(s, far)
    if ack.type == mav.MAV_MISSION_ACCEPTED:
        fail("a mission outside the fence was accepted")
    s.wait_text("outside fence.radius_m")
    t0 = time.time()
    ack = upload(s, items)
    if ack.type != mav.MAV_MISSION_ACCEPTED:
        fail(f"upload: MISSION_ACK {ack.type}; texts: {s.texts}")
    upload_s = time.time() - t0
    back = download(s)
    if [i.command for i in back] != [i.command for i in items] or back[2].param3 != 2.0:
        fail(f"download: {back}")
    # Items there are not, asked for in a loop: each answered, told once (not 50 texts).
    for _ in range(50):
        s.conn.mav.mission_request_int_send(1, 1, 999, mav.MAV_MISSION_TYPE_MISSION)
        s.wait(
            "MISSION_ACK of a missing item",
            lambda m: m.get_type() == "MISSION_ACK"
            and m.type == mav.MAV_MISSION_INVALID_SEQUENCE,
        )
    s.pump(0.5)
    told = [t for t in s.texts if t.startswith("mission download: no item 999")]
    if len(told) != 1:
        fail(f"missing items told {len(told)} times: {told}")
    arm(s)
    s.wait("ATTITUDE", lambda m: m.get_type() == "ATTITUDE")
    # Started as QGroundControl and MAVSDK start a mission on PX4: the Mission mode (AUTO,
    # MISSION) asked for, here as MAVSDK's DO_SET_MODE with the armed flag.
    after_ramp(s, mav.MAV_CMD_DO_SET_MODE, [129, AUTO, MISSION_SUB, 0, 0, 0, 0])
    reached, current, states = [], [], set()
    end = time.time() + 120
    while time.time() < end:
        m = s.pump()
        if m is None:
            continue
        kind = m.get_type()
        if kind == "MISSION_ITEM_REACHED":
            reached.append(m.seq)
        elif kind == "MISSION_CURRENT":
            if not current or current[-1] != m.seq:
                current.append(m.seq)
            states.add(m.mission_state)
            if m.mission_state == mav.MISSION_STATE_COMPLETE and reached[-1:] == [4]:
                break
    landed_and_disarmed(s)
    return {
        "upload_s": round(upload_s, 3),
        "reached": reached,
        "current": current,
        "states": sorted(states),
    }


def flights(s, n):
    """`n` flights in one run, each armed, flown to 1 m and landed; the wall time of each."""
    # udpin knows no peer before the vehicle's first message: nothing sent earlier arrives.
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    times = []
    for _ in range(n):
        t0 = time.time()
        arm_and_take_off(s, 1.0)
        land(s)
        times.append(round(time.time() - t0, 1))
    return {"flights": n, "flight_s": times}


def land_param(s):
    """A landing speed set in flight (a key that takes effect in flight), then the landing."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    arm_and_take_off(s, 2.0)
    s.conn.mav.param_set_send(1, 1, b"CMD_LAND_M_S", 0.3, mav.MAV_PARAM_TYPE_REAL32)
    value = s.param("CMD_LAND_M_S").param_value
    if abs(value - 0.3) > 1e-6:
        fail(f"CMD_LAND_M_S set in the air came back as {value}; texts: {s.texts}")
    land(s)
    return {"land_m_s": round(value, 3)}


def log_download(s, max_bytes):
    """One flight, then the newest log (this run's) downloaded while telemetry goes on:
    bytes, seconds, the rate, and ATTITUDE's rate during it."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    arm_and_take_off(s, 1.0)
    land(s)
    s.conn.mav.log_request_list_send(1, 1, 0, 0xFFFF)
    entries = {}
    end = time.time() + LONG
    while time.time() < end:
        m = s.pump()
        if m is not None and m.get_type() == "LOG_ENTRY":
            entries[m.id] = m
            if len(entries) >= m.num_logs:
                break
    if not entries or max(entries) == 0:
        fail(f"no log listed: {entries}; texts: {s.texts}")
    entry = entries[max(entries)]
    want = entry.size if max_bytes == 0 else min(entry.size, max_bytes)
    data = bytearray(want)
    have = [False] * ((want + 89) // 90)
    attitude, t0 = 0, time.time()
    s.conn.mav.log_request_data_send(1, 1, entry.id, 0, want)
    last_packet = time.time()
    while not all(have) and time.time() - t0 < 600:
        m = s.pump()
        if m is None:
            if time.time() - last_packet > 2.0:
                # Lost packets: the first gap asked for again, as ground stations do.
                k = have.index(False)
                s.conn.mav.log_request_data_send(1, 1, entry.id, k * 90, want - k * 90)
                last_packet = time.time()
            continue
        kind = m.get_type()
        if kind == "ATTITUDE":
            attitude += 1
        elif kind == "LOG_DATA" and m.id == entry.id and m.ofs < want:
            last_packet = time.time()
            n = min(m.count, want - m.ofs)
            data[m.ofs : m.ofs + n] = bytes(m.data[:n])
            have[m.ofs // 90] = True
    seconds = time.time() - t0
    if not all(have):
        fail(f"log {entry.id}: {sum(have)} of {len(have)} packets in {seconds:.0f} s")
    s.conn.mav.log_request_end_send(1, 1)
    topics = []
    if want == entry.size:
        from pyulog import ULog

        path = os.path.join(os.environ.get("TMPDIR", "/tmp"), f"uquad-dl-{os.getpid()}.ulg")
        with open(path, "wb") as f:
            f.write(data)
        topics = sorted({d.name for d in ULog(path).data_list})
        os.remove(path)
    return {
        "log_id": entry.id,
        "num_logs": entry.num_logs,
        "size": entry.size,
        "bytes": want,
        "seconds": round(seconds, 2),
        "rate_b_s": round(want / seconds, 1),
        "attitude_hz": round(attitude / seconds, 1),
        "topics": topics,
    }


def guided(s):
    """In hold, SET_POSITION_TARGET_LOCAL_NED 3 m north of where the vehicle is, streamed at
    10 Hz for 2 s then stopped: the time it took to come within 0.5 m, and how far it was
    from the point 3 s after."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    arm_and_take_off(s, 1.5)
    lp = s.wait("LOCAL_POSITION_NED", lambda m: m.get_type() == "LOCAL_POSITION_NED")
    target = (lp.x + 3.0, lp.y, lp.z)
    position_only = 0b1111_1111_1000
    t0, last_sent, reached = time.time(), 0.0, None
    while time.time() - t0 < LONG:
        now = time.time()
        if now - t0 < 2.0 and now - last_sent >= 0.1:
            last_sent = now
            s.conn.mav.set_position_target_local_ned_send(
                0, 1, 1, mav.MAV_FRAME_LOCAL_NED, position_only, *target, 0, 0, 0, 0, 0, 0, 0, 0
            )
        m = s.pump(0.05)
        if m is not None and m.get_type() == "LOCAL_POSITION_NED":
            if math.hypot(m.x - target[0], m.y - target[1]) < 0.5:
                reached = time.time() - t0
                break
    if reached is None:
        fail(f"the target 3 m north was not reached; texts: {s.texts}")
    end, worst = time.time() + 3.0, 0.0
    while time.time() < end:
        m = s.pump()
        if m is not None and m.get_type() == "LOCAL_POSITION_NED":
            worst = max(worst, math.hypot(m.x - target[0], m.y - target[1]))
    land(s)
    return {"reached_s": round(reached, 2), "held_err_max_m": round(worst, 2)}


def calibrate(s):
    """MAV_CMD_PREFLIGHT_CALIBRATION (gyro) disarmed, once the estimate runs: accepted; the
    next arm waits for the new calibration; asked in the air: denied with the reason."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    s.wait("ATTITUDE", lambda m: m.get_type() == "ATTITUDE")
    gyro = [1, 0, 0, 0, 0, 0, 0]
    s.command(mav.MAV_CMD_PREFLIGHT_CALIBRATION, gyro)
    arm_and_take_off(s, 1.0)
    s.command(mav.MAV_CMD_PREFLIGHT_CALIBRATION, gyro, mav.MAV_RESULT_DENIED)
    s.wait_text("calibrate refused: hold: the IMU calibrates at rest, disarmed")
    # The magnetometer's is not uquad's: unsupported.
    s.command(mav.MAV_CMD_PREFLIGHT_CALIBRATION, [0, 1, 0, 0, 0, 0, 0], mav.MAV_RESULT_UNSUPPORTED)
    land(s)
    return {"calibrated": True}


def until_taken(s, cmd, p, waiting):
    """Sends `cmd` until it is accepted, again while it is refused for a reason in `waiting`
    (the refusal's text names it); any other refusal fails."""
    end = time.time() + LONG
    while time.time() < end:
        told = len(s.texts)
        s.conn.mav.command_long_send(1, 1, cmd, 0, *p)
        ack = s.wait(
            f"COMMAND_ACK of {cmd}",
            lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd,
        )
        if ack.result == mav.MAV_RESULT_ACCEPTED:
            return
        # The refusal's text may still be coming (a long text goes in chunks; another text
        # may come first).
        until = time.time() + 2.0
        while not any("refused" in t for t in s.texts[told:]) and time.time() < until:
            s.pump()
        if not any(w in t for t in s.texts[told:] for w in waiting):
            fail(f"command {cmd} refused ({ack.result}): {s.texts[told:]}")
        time.sleep(0.2)
    fail(f"command {cmd} never taken")


POSCTL = px4_mode(3, 0)


def rc_channels(s):
    """RC_CHANNELS from a simulated SBUS transmitter whose sticks are centred, its throttle
    low and its switches off: the channels as pulse widths, five of them each second."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    first = s.wait("RC_CHANNELS", lambda m: m.get_type() == "RC_CHANNELS")
    t0, n = time.time(), 0
    while time.time() - t0 < 2.0:
        m = s.pump()
        if m is not None and m.get_type() == "RC_CHANNELS":
            n += 1
    chans = [getattr(first, f"chan{i}_raw") for i in range(1, 19)]
    return {"chancount": first.chancount, "chans": chans, "rssi": first.rssi, "per_2s": n}


def joystick_for(s, x, z, seconds, until=None):
    """MANUAL_CONTROL at 10 Hz as QGroundControl's virtual joystick sends it (x the pitch
    stick, z the throttle, 500 its centre) for `seconds`, or until a message passes `until`;
    the newest LOCAL_POSITION_NED at the end."""
    end, last_sent = time.time() + seconds, 0.0
    while time.time() < end:
        now = time.time()
        if now - last_sent >= 0.1:
            last_sent = now
            s.conn.mav.manual_control_send(1, x, 0, z, 0, 0)
        m = s.pump(0.05)
        if until is not None and m is not None and until(m):
            return s.last.get("LOCAL_POSITION_NED")
    if until is not None:
        fail(f"the joystick's wait ended: {s.texts}")
    return s.last.get("LOCAL_POSITION_NED")


def joystick_on_vehicle_clock(s, x, z, seconds):
    """joystick_for, timed on the vehicle's clock (LOCAL_POSITION_NED's time_boot_ms): a busy
    machine that slows the simulation does not shorten what the vehicle flies. At most LONG
    seconds of the client's clock."""
    first, t0 = None, time.time()
    while time.time() - t0 < LONG:
        p = joystick_for(s, x, z, 0.1)
        if p is None:
            continue
        first = first or p
        if (p.time_boot_ms - first.time_boot_ms) / 1000.0 >= seconds:
            return p
    fail(f"the vehicle's clock did not reach {seconds} s: {s.texts}")


def joystick(s):
    """A ground station's joystick: Position chosen on the ground (QGroundControl's SET_MODE
    POSCTL), armed, the throttle raised takes off into Position; the pitch stick forward for
    3 s flies forward, then centred holds; in Hold the same stick moves nothing; land."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    s.wait("ATTITUDE", lambda m: m.get_type() == "ATTITUDE")
    set_mode_as_qgc(s, POSCTL, "position on the ground")
    arm(s)
    # The throttle at its centre while the ESCs' start-up ramp runs, then raised.
    joystick_for(s, 0, 500, 3.0)
    in_position = lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == POSCTL
    joystick_for(s, 0, 1000, LONG, in_position)
    start = joystick_for(s, 0, 500, 2.0)
    joystick_for(s, 1000, 500, 3.0)
    flown = joystick_for(s, 0, 500, 4.0)
    moved = math.hypot(flown.x - start.x, flown.y - start.y)
    set_mode_as_qgc(s, HOLD, "hold in the air")
    s.wait_text("mode hold: command hold")
    # Settled in its hold (the stop from the stick's speed over) before the stick moves; both
    # on the vehicle's clock (8 and 6 s: what 4 and 3 s of this clock fly at twice its pace).
    before = joystick_on_vehicle_clock(s, 0, 500, 8.0)
    after = joystick_on_vehicle_clock(s, 1000, 500, 6.0)
    held = math.hypot(after.x - before.x, after.y - before.y)
    land(s)
    return {"moved_m": round(moved, 2), "held_moved_m": round(held, 2)}


def motor_test(s):
    """MAV_CMD_DO_MOTOR_TEST of each motor in turn as QGroundControl sends it (10 % for 1 s),
    once the estimate runs, each after the last one ended; one out of bounds; a long one
    stopped by a throttle of 0; then armed: refused with the reason."""
    s.wait("a heartbeat", lambda m: m.get_type() == "HEARTBEAT", 5.0)
    s.wait("ATTITUDE", lambda m: m.get_type() == "ATTITUDE")
    test = mav.MAV_CMD_DO_MOTOR_TEST
    running = ["a motor test of motor"]
    for motor in (1, 2, 3, 4):
        until_taken(s, test, [motor, mav.MOTOR_TEST_THROTTLE_PERCENT, 10, 1, 0, 2, 0], running)
    s.command(test, [1, mav.MOTOR_TEST_THROTTLE_PERCENT, 50, 1, 0, 2, 0], mav.MAV_RESULT_DENIED)
    s.wait_text("up to 30 %")
    # A long test of motor 1, stopped at once by a throttle of 0 (the clients' stop).
    until_taken(s, test, [1, mav.MOTOR_TEST_THROTTLE_PERCENT, 10, 5, 0, 2, 0], running)
    s.command(test, [1, mav.MOTOR_TEST_THROTTLE_PERCENT, 0, 0, 0, 2, 0])
    arm_wait = running + ["arm refused: imu:", "arm refused: estimator:"]
    until_taken(s, mav.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0, 0, 0, 0, 0, 0], arm_wait)
    s.command(test, [2, mav.MOTOR_TEST_THROTTLE_PERCENT, 10, 1, 0, 2, 0], mav.MAV_RESULT_DENIED)
    s.wait_text("refused: armed: a motor test runs only disarmed")
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, [0, 0, 0, 0, 0, 0, 0])
    s.wait("disarmed", lambda m: m.get_type() == "HEARTBEAT"
           and not m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    return {"tested": [1, 2, 3, 4], "texts": [t for t in s.texts if "motor" in t]}


def main():
    pty = sys.argv[1] == "download-pty"
    s = Station(pty=pty)
    if pty:
        print(f"pty {s.conn.name}", flush=True)
    else:
        print(f"port {s.port}", flush=True)
    if sys.stdin.readline().strip() != "started":
        fail("expected `started`")
    started = time.time()
    line = sys.stdin.readline().strip()
    if not line.startswith("run "):
        fail("expected `run DIR`")
    run_dir = line[4:]
    if sys.argv[1] == "fly":
        out = fly(s, run_dir, started, int(sys.argv[2]))
    elif sys.argv[1] == "signed":
        out = signed(s)
    elif sys.argv[1] == "stalled":
        out = stalled(s, started)
    elif sys.argv[1] == "mission":
        out = mission(s)
    elif sys.argv[1] == "before-arm":
        out = before_arm(s)
    elif sys.argv[1] in ("download", "download-pty"):
        out = log_download(s, int(sys.argv[2]))
    elif sys.argv[1] == "calibrate":
        out = calibrate(s)
    elif sys.argv[1] == "guided":
        out = guided(s)
    elif sys.argv[1] == "land-param":
        out = land_param(s)
    elif sys.argv[1] == "rc-channels":
        out = rc_channels(s)
    elif sys.argv[1] == "joystick":
        out = joystick(s)
    elif sys.argv[1] == "motor-test":
        out = motor_test(s)
    elif sys.argv[1] == "flights":
        out = flights(s, int(sys.argv[2]))
    else:
        out = link_loss(s, started)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
