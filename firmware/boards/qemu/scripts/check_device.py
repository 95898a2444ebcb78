#!/usr/bin/env python3
"""End-to-end check of the brightpix QEMU device (firmware/README.md, "Running the QEMU device").

Runs the firmware ELF in qemu-system-arm exactly as the contract says (UART0 on a unix
socket, `--pixels FIFO` on the semihosting command line) and, with its own implementation
of shared/PROTOCOL.md (COBS, CRC-32, postcard; Python standard library only):

1. Hello -> HelloReply (version, schema hash from PROTOCOL.md, board name, capabilities);
2. uploads a CANARY-like configuration (112x112, 7x7 windows of 16x16, background map of
   50 counts, subtract-next N=20) in chunks, commit -> ConfigApplied;
3. streams frames as PixelRows over UART0, then as PixelRows frames through the FIFO, and
   collects Slopes/FrameDone; reports frames/s for both paths; a StatusRequest sent while
   the FIFO stream flows must be answered;
4. closes the FIFO (the device must keep answering on UART0: StatusRequest round trip),
   reopens it and streams more; uploads a second configuration (subtract-mean M=4, N=12,
   threshold, level filter) and streams through the FIFO again;
5. a frame with a corrupted CRC is counted and answered with Error(Crc);
6. compares every slope and validity flag with the host: `brightpix process` (the
   firmware's engine on the host, HostEngine) and `brightpix process --reference`.

Usage: check_device.py [--elf ELF] [--brightpix BIN] [--uart-frames N] [--fifo-frames N]
                       [--regular-file]
Needs qemu-system-arm; the brightpix host binary (default: target/release/brightpix at the
repository root; build it with `cargo build --release -p brightpix`); defmt-print is used to
show the device log if it is on PATH.
"""

import argparse
import array
import math
import os
import queue
import random
import re
import signal
import stat
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
FIRMWARE = os.path.normpath(os.path.join(HERE, "..", "..", ".."))
REPO = os.path.dirname(FIRMWARE)
DEFAULT_ELF = os.path.join(FIRMWARE, "target", "thumbv7em-none-eabihf", "release", "brightpix-qemu")
DEFAULT_BRIGHTPIX = os.path.join(REPO, "target", "release", "brightpix")

WIDTH = HEIGHT = 112
SIDE = 16
ACROSS = 7
BACKGROUND_COUNTS = 50
PIXELS_PER_MESSAGE = 480
CHUNK_BYTES = 960

# --------------------------------------------------------------------------------------
# Wire format (shared/PROTOCOL.md)
# --------------------------------------------------------------------------------------


def cobs_encode(data):
    out = bytearray()
    block = bytearray()
    for b in data:
        if b == 0:
            out.append(len(block) + 1)
            out += block
            block = bytearray()
        else:
            block.append(b)
            if len(block) == 254:
                out.append(255)
                out += block
                block = bytearray()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(data):
    out = bytearray()
    i = 0
    while i < len(data):
        code = data[i]
        if code == 0 or i + code > len(data):
            raise ValueError("bad COBS")
        out += data[i + 1:i + code]
        i += code
        if code < 255 and i < len(data):
            out.append(0)
    return bytes(out)


def frame(body):
    return cobs_encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"


def unframe(stuffed):
    raw = cobs_decode(stuffed)
    if len(raw) < 5:
        raise ValueError("short frame")
    body, crc = raw[:-4], int.from_bytes(raw[-4:], "little")
    if zlib.crc32(body) != crc:
        raise ValueError("CRC mismatch")
    return body


def varint(n):
    out = bytearray()
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def zigzag(n):
    return varint((n << 1) ^ (n >> 63) if n < 0 else n << 1)


def blob(b):
    return varint(len(b)) + bytes(b)


class Reader:
    def __init__(self, body):
        self.b = body
        self.i = 0

    def u8(self):
        v = self.b[self.i]
        self.i += 1
        return v

    def varint(self):
        shift = v = 0
        while True:
            byte = self.u8()
            v |= (byte & 0x7F) << shift
            shift += 7
            if byte < 0x80:
                return v

    def zigzag(self):
        v = self.varint()
        return (v >> 1) ^ -(v & 1)

    def bool(self):
        v = self.u8()
        if v > 1:
            raise ValueError("bad bool")
        return v == 1

    def option(self, f):
        return f() if self.bool() else None

    def bytes(self):
        n = self.varint()
        v = self.b[self.i:self.i + n]
        self.i += n
        return bytes(v)

    def rest(self):
        return self.b[self.i:]


# HostMessage
def msg_hello(version, schema, session=0xC4EC):
    return bytes([0]) + varint(version) + varint(schema) + varint(session)


RULES = {"threshold": (0,), "subtract-next": (1,), "subtract-next-distinct": (2,)}


def msg_config_begin(upload_id, *, rule, n, mean_count=None, level_filter=None, threshold=None,
                     min_flux=0, windows, background, gain=False, reference_slopes=False):
    rule_bytes = varint(3) + varint(mean_count) if rule == "subtract-mean" else varint(RULES[rule][0])
    header = (varint(WIDTH) + varint(HEIGHT) + bytes([16])  # camera
              + varint(windows)
              + rule_bytes
              + varint(0) + varint(n)  # PixelCountMode::All(n)
              + (bytes([1, level_filter]) if level_filter is not None else b"\x00")
              + (b"\x01" + zigzag(threshold) if threshold is not None else b"\x00")
              + zigzag(min_flux)
              # Background: 0 None, 1 Map (a table follows), 2 Constant(i32)
              + bytes([background, gain, reference_slopes])
              + b"\x00")  # crop: None, the camera is the whole sensor

    return bytes([1]) + varint(upload_id) + header


def config_header_of(begin):
    """The header's encoding inside a ConfigBegin body: the start of the digest (§7)."""
    r = Reader(begin)
    r.varint()  # message kind
    r.varint()  # upload id
    return r.rest()


def msg_config_chunk(upload_id, table, offset, data):
    return bytes([2]) + varint(upload_id) + varint(table) + varint(offset) + blob(data)


def msg_config_commit(upload_id, crc):
    return bytes([3]) + varint(upload_id) + varint(crc)


def msg_status_request():
    return bytes([5])


def msg_pixel_rows(frame_id, first_pixel, pixel_bytes):
    return bytes([7]) + varint(frame_id) + varint(first_pixel) + blob(pixel_bytes)


TABLE_WINDOWS, TABLE_BACKGROUND = 0, 2
ACKS = ["UploadStarted", "ChunkStored", "ConfigApplied", "UploadAborted", "LevelFiltersReset",
        "CaptureStarted", "CaptureStopped", "BenchDone"]
ERRORS = ["Decode", "Crc", "FrameTooLong", "HelloRequired", "Unexpected", "NoUpload",
          "UploadMismatch", "ChunkOutOfOrder", "ChunkLength", "ChunkPastEnd", "UploadIncomplete",
          "UploadCrc", "Capacity", "Config", "NotConfigured", "Frame", "NoCamera", "Crop", "Bench",
          "Sync"]
COUNT_UNITS = ["Cycles", "Instructions", "Uncounted"]
BENCH_LIMITS = ["Pixels", "Windows", "EngineMemory"]
FLOOR_CHECKS = ["Equal", "NotComparable"]
SOURCES = ["Link", "Stream", "Camera"]
ERRATUM_FIXES = ["NotNeeded", "Applied", "Failed"]


def decode_device(body):
    """DeviceMessage -> (kind, fields)."""
    r = Reader(body)
    kind = r.varint()
    if kind == 0:
        version, schema, session = r.varint(), r.varint(), r.varint()
        caps = dict(max_subapertures=r.varint(), max_camera_pixels=r.varint(),
                    max_open_windows=r.varint(), pool_entries=r.varint(),
                    history_pixels=r.varint(), scratch_entries=r.varint(),
                    max_results_per_row=r.varint(), max_frame_bytes=r.varint(),
                    pixel_source=SOURCES[r.varint()], board=r.bytes().decode())
        return "HelloReply", dict(version=version, schema=schema, session=session,
                                  capabilities=caps)
    if kind == 1:
        variant = r.varint()
        name = ACKS[variant]
        if name == "ChunkStored":
            f = dict(upload_id=r.varint(), table=r.varint(), end=r.varint())
        elif name == "ConfigApplied":
            f = dict(config_id=r.varint(), open_windows=r.varint(), pool_entries=r.varint())
        elif name == "UploadAborted":
            f = dict(upload_id=r.option(r.varint))
        elif name == "LevelFiltersReset":
            f = {}
        else:
            f = dict(value=r.varint())
        return "Ack", dict(ack=name, **f)
    if kind == 2:
        variant = r.varint()
        f = dict(error=ERRORS[variant], rest=r.rest().hex())
        if ERRORS[variant] == "Frame":
            f["frame"] = r.varint()
            f["fault"] = r.varint()
        return "Error", f
    if kind == 3:
        return "Status", dict(config_id=r.option(r.varint), upload_id=r.option(r.varint),
                              capturing=r.bool(), frames_processed=r.varint(),
                              frames_dropped=r.varint(), crc_errors=r.varint(),
                              decode_errors=r.varint(), overruns=r.varint(),
                              pixel_errors=r.varint(), session=r.option(r.varint),
                              reset_reason=r.varint(), watchdog_ms=r.option(r.varint),
                              health=decode_health(r), config_digest=r.option(r.varint),
                              engine=dict(windows=r.varint(), candidates=r.varint(),
                                          compactions=r.varint(), rescans=r.varint(),
                                          attentions=r.varint(), kernel_frames=r.varint()))
    if kind == 4:
        frame_id = r.varint()
        entries = []
        for _ in range(r.varint()):
            entries.append((r.varint(), r.zigzag(), r.zigzag(), r.zigzag(), r.bool()))
        return "Slopes", dict(frame=frame_id, results=entries)
    if kind == 5:
        return "FrameDone", dict(frame=r.varint(), count=r.varint())
    if kind == 6:
        return "BenchReport", decode_bench_report(r)
    if kind == 7:
        return "CaptureBegan", dict(synced=r.bool(), camera_frame=r.option(r.varint))
    if kind == 8:
        return "EdgeRows", dict(frame=r.varint(), first=r.varint(), last=r.varint())
    raise ValueError("unknown device message %d" % kind)


def decode_bench_report(r):
    """BenchReport (PROTOCOL.md §14), as serde's JSON of it."""
    spread = lambda: dict(min=r.varint(), median=r.varint(), max=r.varint())
    report = dict(workload=r.bytes().decode(), unit=COUNT_UNITS[r.varint()],
                  clock_hz=r.option(r.varint), pixels=r.varint(), frames=r.varint())
    variant = r.varint()
    if variant == 0:
        result = {"Measured": dict(engine_total=r.varint(), engine_frame=spread(),
                                   engine_last_row=spread(), floor_total=r.varint(),
                                   floor_frame=spread(), floor_last_row=spread(),
                                   floor_check=FLOOR_CHECKS[r.varint()])}
    elif variant == 1:
        result = {"DoesNotFit": dict(limit=BENCH_LIMITS[r.varint()])}
    elif variant == 2:
        result = {"SlopesDiffer": dict(window=r.varint())}
    else:
        raise ValueError("unknown bench result %d" % variant)
    report["result"] = result
    if r.rest():
        raise ValueError("bytes after a BenchReport")
    return report


def decode_health(r):
    """Status.health (PROTOCOL.md §5): seven options; u8 is one byte, wider
    integers are varints."""
    silicon = r.option(lambda: dict(device_id=r.varint(), revision_id=r.varint(),
                                    axi_sram_fix=r.varint()))
    clocks = r.option(lambda: dict(sysclk_configured_hz=r.varint(), sysclk_read_hz=r.varint(),
                                   voltage_scale_configured=r.u8(), voltage_scale_read=r.u8(),
                                   voltage_ready=r.bool()))
    usb_clock = r.option(lambda: dict(sync_source=r.u8(), synced=r.bool(), trim=r.u8(),
                                      sync_errors=r.varint()))
    stack = r.option(lambda: dict(size=r.varint(), peak=r.varint(), guarded=r.bool()))
    camera = r.option(lambda: dict(overruns=r.varint(), sync_errors=r.varint(),
                                   dma_transfer_errors=r.varint(), dma_fifo_errors=r.varint(),
                                   fifo_not_drained=r.varint()))
    idle = r.option(r.varint)
    fault = lambda: dict(kind=["HardFault"][r.varint()], pc=r.varint(), lr=r.varint(),
                         cfsr=r.varint(), hfsr=r.varint(), mmfar=r.varint(), bfar=r.varint())
    faults = r.option(lambda: dict(before_reset=r.option(fault)))
    return dict(silicon=silicon, clocks=clocks, usb_clock=usb_clock, stack=stack,
                camera_interface=camera, idle_permille=idle, faults=faults)


def schema_from_protocol_md():
    with open(os.path.join(REPO, "shared", "PROTOCOL.md")) as f:
        text = f.read()
    version = int(re.search(r"wire protocol, version (\d+)", text).group(1))
    schema = int(re.search(r"Schema hash of this document's messages: \*\*`(0x[0-9a-f]+)`", text).group(1), 16)
    return version, schema


# --------------------------------------------------------------------------------------
# The device in QEMU
# --------------------------------------------------------------------------------------


class Device:
    """QEMU running the firmware; UART0 on a unix socket; a reader thread decodes
    everything the device sends: Slopes/FrameDone are collected, replies queued."""

    def __init__(self, elf, tmp, fifo):
        self.sock_path = os.path.join(tmp, "uart0.sock")
        self.log_path = os.path.join(tmp, "defmt.bin")
        args = ",arg=brightpix-qemu,arg=--pixels,arg=" + fifo
        cmd = ["qemu-system-arm", "-cpu", "cortex-m4", "-machine", "mps2-an386",
               "-display", "none", "-monitor", "none",
               "-serial", "unix:%s,server=on,wait=on" % self.sock_path,
               "-semihosting-config", "enable=on,target=native" + args,
               "-kernel", elf]
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while True:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self.sock.connect(self.sock_path)
                break
            except (FileNotFoundError, ConnectionRefusedError):
                self.sock.close()
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise RuntimeError("QEMU did not open the UART socket: %r" % (self.proc.communicate(),))
                time.sleep(0.02)
        self.replies = queue.Queue()
        self.slopes = {}      # frame -> {index: (slope_x, slope_y, flux, valid)}
        self.done = {}        # frame -> count
        self.errors = []
        self.done_event = threading.Condition()
        self.thread = threading.Thread(target=self._reader, daemon=True)
        self.thread.start()

    def _reader(self):
        buf = bytearray()
        while True:
            try:
                chunk = self.sock.recv(65536)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while True:
                z = buf.find(0)
                if z < 0:
                    break
                stuffed, buf = bytes(buf[:z]), buf[z + 1:]
                if not stuffed:
                    continue
                kind, f = decode_device(unframe(stuffed))
                if kind == "Slopes":
                    got = self.slopes.setdefault(f["frame"], {})
                    for (index, sx, sy, flux, valid) in f["results"]:
                        if index in got:
                            self.errors.append(("duplicate result", f["frame"], index))
                        got[index] = (sx, sy, flux, valid)
                elif kind == "FrameDone":
                    with self.done_event:
                        self.done[f["frame"]] = f["count"]
                        self.done_event.notify_all()
                else:
                    if kind == "Error":
                        self.errors.append(f)
                    self.replies.put((kind, f))

    def send(self, body):
        self.sock.sendall(frame(body))

    def request(self, body, timeout=10.0):
        self.send(body)
        return self.replies.get(timeout=timeout)

    def wait_frames(self, frame_ids, timeout):
        deadline = time.monotonic() + timeout
        with self.done_event:
            while not all(f in self.done for f in frame_ids):
                left = deadline - time.monotonic()
                if left <= 0:
                    missing = [f for f in frame_ids if f not in self.done]
                    raise RuntimeError("no FrameDone for %d frames (first %d)" % (len(missing), missing[0]))
                self.done_event.wait(left)

    def cpu_seconds(self):
        with open("/proc/%d/stat" % self.proc.pid) as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def close(self):
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.sock.close()
        self.log.close()

    def defmt_lines(self, elf):
        try:
            with open(self.log_path, "rb") as f:
                raw = f.read()
            res = subprocess.run(["defmt-print", "-e", elf], input=raw, capture_output=True, timeout=30)
        except (FileNotFoundError, subprocess.TimeoutExpired):
            return ["(defmt-print not available)"]
        text = res.stdout.decode(errors="replace")
        return [l for l in text.splitlines() if l.strip()]


# --------------------------------------------------------------------------------------
# Frames, configuration, host reference
# --------------------------------------------------------------------------------------


def spot_frame(rng):
    """A Shack-Hartmann-like frame: a Gaussian spot (200 photons) per sub-aperture at a
    random offset, 50 counts of background, +-3 counts of uniform noise."""
    px = array.array("H", bytes(2 * WIDTH * HEIGHT))
    norm = 200.0 / (2.0 * math.pi * 2.25)
    for sy in range(ACROSS):
        for sx in range(ACROSS):
            cx = 7.5 + (rng.random() - 0.5) * 6.0
            cy = 7.5 + (rng.random() - 0.5) * 6.0
            for j in range(SIDE):
                row = (sy * SIDE + j) * WIDTH + sx * SIDE
                for i in range(SIDE):
                    r2 = (i - cx) ** 2 + (j - cy) ** 2
                    v = BACKGROUND_COUNTS + norm * math.exp(-r2 / 4.5) + (rng.random() - 0.5) * 6.0
                    px[row + i] = int(math.floor(v + 0.5))
    return px


def special_frames():
    flat = array.array("H", [BACKGROUND_COUNTS] * (WIDTH * HEIGHT))  # ties everywhere
    zero = array.array("H", [0] * (WIDTH * HEIGHT))                  # below background
    sat = array.array("H", [BACKGROUND_COUNTS] * (WIDTH * HEIGHT))   # saturated patches
    for y in range(HEIGHT):
        for x in range(WIDTH):
            if (x % SIDE) in (3, 4, 5) and (y % SIDE) in (9, 10):
                sat[y * WIDTH + x] = 65535
    return [flat, zero, sat]


def le_bytes(px):
    a = array.array("H", px)
    if sys.byteorder == "big":
        a.byteswap()
    return a.tobytes()


def pixel_rows_frames(frame_id, px):
    raw = le_bytes(px)
    out = bytearray()
    step = 2 * PIXELS_PER_MESSAGE
    for first in range(0, len(raw), step):
        out += frame(msg_pixel_rows(frame_id, first // 2, raw[first:first + step]))
    return bytes(out)


def windows_table():
    out = bytearray()
    for sy in range(ACROSS):
        for sx in range(ACROSS):
            for v in (sx * SIDE, sy * SIDE, SIDE, SIDE):
                out += v.to_bytes(2, "little")
    return bytes(out)


def background_table():
    return (BACKGROUND_COUNTS * 16).to_bytes(4, "little", signed=True) * (WIDTH * HEIGHT)


CONFIGS = {
    # name: (header keywords, TOML selection/calibration lines)
    "canary": (dict(rule="subtract-next", n=20),
               '[selection]\nrule = "subtract-next"\npixels = 20\n', ""),
    "mean": (dict(rule="subtract-mean", n=12, mean_count=4, level_filter=3, threshold=16),
             '[selection]\nrule = "subtract-mean"\nmean_count = 4\npixels = 12\n'
             "[selection.level_filter]\ngain_shift = 3\n",
             "threshold_counts = 1.0\n"),
}


def toml_for(name):
    _, selection, calibration = CONFIGS[name]
    return ("[camera]\nwidth = %d\nheight = %d\nbit_depth = 16\n\n"
            "[subapertures.grid]\nx = 0\ny = 0\ncolumns = %d\nrows = %d\nwidth = %d\nheight = %d\n\n"
            "[calibration]\nbackground_counts = %d\n%s\n%s\n"
            "[centroid]\nmin_flux_counts = 0.0\n"
            % (WIDTH, HEIGHT, ACROSS, ACROSS, SIDE, SIDE, BACKGROUND_COUNTS, calibration, selection))


def upload(dev, upload_id, name):
    header, _, _ = CONFIGS[name]
    tables = [(TABLE_WINDOWS, windows_table()), (TABLE_BACKGROUND, background_table())]
    begin = msg_config_begin(upload_id, windows=ACROSS * ACROSS, background=True, **header)
    reply = dev.request(begin)
    assert reply == ("Ack", dict(ack="UploadStarted", value=upload_id)), reply
    # The commit's CRC is the configuration's digest: the header, then the tables.
    crc = zlib.crc32(config_header_of(begin))
    for table, data in tables:
        for off in range(0, len(data), CHUNK_BYTES):
            part = data[off:off + CHUNK_BYTES]
            crc = zlib.crc32(part, crc)
            kind, f = dev.request(msg_config_chunk(upload_id, table, off, part))
            assert kind == "Ack" and f["ack"] == "ChunkStored" and f["end"] == off + len(part), (kind, f)
    return dev.request(msg_config_commit(upload_id, crc))


def write_npy_u16(path, frames):
    header = "{'descr': '<u2', 'fortran_order': False, 'shape': (%d, %d, %d), }" % (len(frames), HEIGHT, WIDTH)
    header += " " * ((64 - (10 + len(header) + 1) % 64) % 64) + "\n"
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode())
        for px in frames:
            f.write(le_bytes(px))


def read_npy(path):
    with open(path, "rb") as f:
        data = f.read()
    assert data[:6] == b"\x93NUMPY"
    if data[6] == 1:
        hlen, start = int.from_bytes(data[8:10], "little"), 10
    else:
        hlen, start = int.from_bytes(data[8:12], "little"), 12
    header = data[start:start + hlen].decode()
    descr = re.search(r"'descr': '([^']+)'", header).group(1)
    shape = tuple(int(x) for x in re.search(r"'shape': \(([^)]*)\)", header).group(1).split(",") if x.strip())
    code = {"<f8": "d", "|u1": "B", "<u1": "B"}[descr]
    arr = array.array(code, data[start + hlen:])
    return shape, arr


def host_results(brightpix, tmp, name, frames, reference):
    cfg = os.path.join(tmp, "%s.toml" % name)
    with open(cfg, "w") as f:
        f.write(toml_for(name))
    frames_path = os.path.join(tmp, "%s-frames.npy" % name)
    write_npy_u16(frames_path, frames)
    out = os.path.join(tmp, "%s-slopes%s.npy" % (name, "-ref" if reference else ""))
    valid = out.replace(".npy", "-valid.npy")
    cmd = [brightpix, "process", "--config", cfg, "--frames", frames_path, "--out", out, "--valid-out", valid]
    if reference:
        cmd.append("--reference")
    subprocess.run(cmd, check=True, capture_output=True)
    shape, slopes = read_npy(out)
    _, valid_flags = read_npy(valid)
    n = ACROSS * ACROSS
    assert shape == (len(frames), n, 2), shape
    return [[(slopes[(k * n + s) * 2], slopes[(k * n + s) * 2 + 1], valid_flags[k * n + s])
             for s in range(n)] for k in range(len(frames))]


def compare(dev, frame_ids, expected, what):
    mismatches = []
    for fid, exp in zip(frame_ids, expected):
        got = dev.slopes.get(fid, {})
        if dev.done.get(fid) != len(exp) or len(got) != len(exp):
            mismatches.append((fid, "count", dev.done.get(fid), len(got)))
            continue
        for s, (ex, ey, ev) in enumerate(exp):
            sx, sy, _, valid = got[s]
            if (sx / 65536.0, sy / 65536.0, int(valid)) != (ex, ey, ev):
                mismatches.append((fid, s, (sx / 65536.0, sy / 65536.0, valid), (ex, ey, ev)))
    check(not mismatches, "%s: %d frames x %d sub-apertures bit-exact%s"
          % (what, len(frame_ids), len(expected[0]) if expected else 0,
             "" if not mismatches else "; first mismatches: %r" % mismatches[:3]))


def write_pixels(path, data):
    """One batch of PixelRows frames into the FIFO: open, write, close. While the FIFO is
    open for writing and empty, the device blocks in its read (UART0 too). A regular file
    is appended to."""
    fd = os.open(path, os.O_WRONLY | (0 if stat.S_ISFIFO(os.stat(path).st_mode) else os.O_APPEND))
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what, flush=True)
    if not cond:
        check.failed = True


check.failed = False


def check_vectors():
    """This client against shared/protocol-vectors.json: every device frame
    unframes to its body and decodes to the vector's message kind (and, for
    HelloReply and Status, to its fields); the Hello this script sends
    encodes to the vector's bytes."""
    import json
    with open(os.path.join(REPO, "shared", "protocol-vectors.json")) as f:
        vectors = json.load(f)["vectors"]
    count = 0
    for v in vectors:
        stuffed = bytes.fromhex(v["frame"])[:-1]
        body = unframe(stuffed)
        assert body.hex(" ") == v["body"], v["name"]
        message = v["message"]
        if v["direction"] == "host":
            if "Hello" in message:
                h = message["Hello"]
                assert msg_hello(h["protocol"]["version"], h["protocol"]["schema"],
                                 h["session"]) == body, v
                assert frame(body) == bytes.fromhex(v["frame"]), v
            continue
        kind, fields = decode_device(body)
        expected = message if isinstance(message, str) else next(iter(message))
        assert kind == expected, (kind, v["name"])
        if kind == "HelloReply":
            h = message["HelloReply"]
            assert (fields["version"], fields["schema"], fields["session"]) == \
                (h["version"], h["schema"], h["session"]), v["name"]
            assert fields["capabilities"]["board"] == h["capabilities"]["board"]
        if kind == "Status":
            st = message["Status"]
            for key in ("frames_processed", "crc_errors", "session", "watchdog_ms",
                        "config_digest", "engine"):
                assert fields[key] == st[key], (key, fields, st)
            health = dict(st["health"])
            if health["silicon"] is not None:
                fix = health["silicon"]["axi_sram_fix"]
                health["silicon"] = dict(health["silicon"], axi_sram_fix=ERRATUM_FIXES.index(fix))
            assert fields["health"] == health, (fields["health"], health)
        if kind in ("BenchReport", "CaptureBegan", "EdgeRows"):
            assert fields == message[kind], (fields, message)
        count += 1
    print("vectors: %d device messages decoded and the Hello encoded as in "
          "shared/protocol-vectors.json" % count)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vectors", action="store_true",
                    help="only check this client against shared/protocol-vectors.json (no QEMU)")
    ap.add_argument("--elf", default=DEFAULT_ELF)
    ap.add_argument("--brightpix", default=DEFAULT_BRIGHTPIX)
    ap.add_argument("--uart-frames", type=int, default=4)
    ap.add_argument("--fifo-frames", type=int, default=200)
    ap.add_argument("--regular-file", action="store_true",
                    help="give --pixels a regular file that the host appends to, not a FIFO")
    opts = ap.parse_args()
    if opts.vectors:
        check_vectors()
        return
    elf = os.path.abspath(opts.elf)
    version, schema = schema_from_protocol_md()
    rng = random.Random(2011)

    with tempfile.TemporaryDirectory() as tmp:
        if opts.regular_file:
            pixels = os.path.join(tmp, "pixels.bin")
            open(pixels, "wb").close()
        else:
            pixels = os.path.join(tmp, "pixels.fifo")
            os.mkfifo(pixels)
        t0 = time.monotonic()
        dev = Device(elf, tmp, pixels)
        try:
            if not opts.regular_file:
                # The device opens the FIFO at boot (QEMU waits in that open until a writer
                # comes); then the host keeps it closed except while writing a batch of frames.
                os.close(os.open(pixels, os.O_WRONLY))
            kind, f = dev.request(msg_hello(version, schema))
            check(kind == "HelloReply" and f["version"] == version and f["schema"] == schema,
                  "Hello -> HelloReply, protocol %d, schema %#x (%.2f s after QEMU start)"
                  % (f.get("version"), f.get("schema"), time.monotonic() - t0))
            caps = f["capabilities"]
            print("     capabilities: %s" % caps)
            check(caps["board"] == "qemu-mps2-an386" and caps["pixel_source"] == "Stream",
                  "board qemu-mps2-an386, pixel source Stream")

            t = time.monotonic()
            kind, f = upload(dev, 1, "canary")
            check(kind == "Ack" and f["ack"] == "ConfigApplied" and f["config_id"] == 1,
                  "CANARY configuration uploaded (windows + 50 KB background map) in %.2f s: %s"
                  % (time.monotonic() - t, f))

            order = []      # (config name, frame id, pixels) in device order
            # --- PixelRows over UART0 ---
            uart = [spot_frame(rng) for _ in range(opts.uart_frames)]
            ids = list(range(1, 1 + len(uart)))
            data = b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, uart))
            t = time.monotonic()
            dev.sock.sendall(data)
            dev.wait_frames(ids, timeout=60 + 5 * len(ids))
            dt = time.monotonic() - t
            uart_rate = len(ids) / dt
            check(True, "UART0 path: %d frames in %.2f s: %.2f frames/s (%.1f KB/s of PixelRows)"
                  % (len(ids), dt, uart_rate, len(data) / dt / 1e3))
            order += [("canary", i, px) for i, px in zip(ids, uart)]

            # --- PixelRows frames through the FIFO ---
            fifo_frames = [spot_frame(rng) for _ in range(opts.fifo_frames)] + special_frames()
            ids = list(range(1001, 1001 + len(fifo_frames)))
            data = b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, fifo_frames))
            t, cpu = time.monotonic(), dev.cpu_seconds()
            writer = threading.Thread(target=write_pixels, args=(pixels, data))
            writer.start()
            # UART0 while the stream flows: a StatusRequest is answered between two runs of pixels.
            time.sleep(0.05)
            t_req = time.monotonic()
            kind, f = dev.request(msg_status_request())
            status_rtt = time.monotonic() - t_req
            writer.join()
            dev.wait_frames(ids, timeout=120)
            dt = time.monotonic() - t
            cpu = dev.cpu_seconds() - cpu
            check(kind == "Status" and 0 < f["frames_processed"] < len(order) + len(ids),
                  "StatusRequest during the stream answered in %.1f ms (%d frames processed by then)"
                  % (status_rtt * 1e3, f.get("frames_processed", -1)))
            fifo_rate = len(ids) / dt
            check(True, "FIFO path: %d frames in %.2f s: %.1f frames/s (%.0f KB/s of PixelRows in, "
                  "Slopes out on UART0); QEMU used %.2f ms of CPU per frame (%.0f frames/s if it "
                  "had a core to itself)"
                  % (len(ids), dt, fifo_rate, len(data) / dt / 1e3, cpu / len(ids) * 1e3,
                     len(ids) / max(cpu, 1e-3)))
            order += [("canary", i, px) for i, px in zip(ids, fifo_frames)]

            # --- the FIFO is closed: UART0 must answer at once; reopen and stream again ---
            time.sleep(0.2)
            rtts = []
            for _ in range(5):
                t = time.monotonic()
                kind, f = dev.request(msg_status_request(), timeout=5)
                rtts.append(time.monotonic() - t)
            check(kind == "Status", "FIFO closed by the host: StatusRequest answered in %.1f ms (median of 5)"
                  % (sorted(rtts)[2] * 1e3))
            more = [spot_frame(rng) for _ in range(5)]
            ids = list(range(2001, 2001 + len(more)))
            write_pixels(pixels, b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, more)))
            dev.wait_frames(ids, timeout=30)
            check(True, "FIFO reopened: %d more frames processed" % len(ids))
            order += [("canary", i, px) for i, px in zip(ids, more)]

            # --- a corrupted frame on the link ---
            bad = bytearray(frame(msg_status_request()))
            bad[1] ^= 0x40
            dev.sock.sendall(bytes(bad))
            kind, f = dev.replies.get(timeout=10)
            check(kind == "Error" and f["error"] == "Crc", "corrupted frame answered with Error(Crc): %s" % (f,))

            # --- a second configuration, more frames through the FIFO ---
            kind, f = upload(dev, 2, "mean")
            check(kind == "Ack" and f["ack"] == "ConfigApplied" and f["config_id"] == 2,
                  "second configuration (subtract-mean M=4 N=12, threshold, level filter): %s" % (f,))
            mean = [spot_frame(rng) for _ in range(20)]
            ids = list(range(3001, 3001 + len(mean)))
            write_pixels(pixels, b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, mean)))
            dev.wait_frames(ids, timeout=30)
            order += [("mean", i, px) for i, px in zip(ids, mean)]

            kind, status = dev.request(msg_status_request())
            n_frames = len(order)
            check(kind == "Status" and status["frames_processed"] == n_frames and status["crc_errors"] == 1
                  and status["frames_dropped"] == 0 and status["decode_errors"] == 0
                  and status["overruns"] == 0 and status["config_id"] == 2,
                  "Status: %s" % (status,))
            check([e for e in dev.errors if e.get("error") != "Crc"] == [],
                  "no other errors from the device: %s" % dev.errors)
        finally:
            dev.close()

        # --- the host's engine and reference on the same frames ---
        for name in ("canary", "mean"):
            frames = [px for (c, _, px) in order if c == name]
            ids = [i for (c, i, _) in order if c == name]
            for reference in (False, True):
                expected = host_results(opts.brightpix, tmp, name, frames, reference)
                compare(dev, ids, expected, "%s vs host %s" % (name, "reference" if reference else "engine (HostEngine)"))

        print("     device log:")
        for line in dev.defmt_lines(elf):
            print("       " + line)
    print("     throughput: UART0 PixelRows %.2f frames/s, FIFO %.1f frames/s" % (uart_rate, fifo_rate))
    print("FAILED" if check.failed else "all checks passed")
    return 1 if check.failed else 0


if __name__ == "__main__":
    sys.exit(main())
