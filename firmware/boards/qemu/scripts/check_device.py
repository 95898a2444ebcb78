#!/usr/bin/env python3
"""End-to-end check of the brightpix QEMU device (firmware/boards/qemu/README.md,
"Running the QEMU device").

Runs the firmware ELF in qemu-system-arm exactly as the contract says (UART0 on a unix
socket, `--pixels FIFO` on the semihosting command line) and, with its own implementation
of shared/PROTOCOL.md (wire.py beside it: COBS, CRC-32, postcard; Python standard library
only):

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
import stat
import subprocess
import sys
import tempfile
import threading
import time
import zlib

from qemu import Qemu
from wire import (
    TABLE_BACKGROUND,
    TABLE_WINDOWS,
    check_vectors,
    config_header_of,
    decode_device,
    frame,
    msg_config_begin,
    msg_config_chunk,
    msg_config_commit,
    msg_hello,
    msg_pixel_rows,
    msg_status_request,
    schema_from_protocol_md,
    unframe,
)

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
# The device in QEMU
# --------------------------------------------------------------------------------------


class Device(Qemu):
    """QEMU running the firmware; UART0 on a unix socket; a reader thread decodes
    everything the device sends: Slopes/FrameDone are collected, replies queued."""

    def __init__(self, elf, tmp, fifo):
        super().__init__(elf, tmp, ["--pixels", fifo])
        self.replies = queue.Queue()
        self.slopes = {}  # frame -> {index: (slope_x, slope_y, flux, valid)}
        self.done = {}  # frame -> count
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
                stuffed, buf = bytes(buf[:z]), buf[z + 1 :]
                if not stuffed:
                    continue
                kind, f = decode_device(unframe(stuffed))
                if kind == "Slopes":
                    got = self.slopes.setdefault(f["frame"], {})
                    for index, sx, sy, flux, valid in f["results"]:
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
                    raise RuntimeError(
                        f"no FrameDone for {len(missing)} frames (first {missing[0]})"
                    )
                self.done_event.wait(left)

    def close(self):
        self.stop()


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
                    px[row + i] = math.floor(v + 0.5)
    return px


def special_frames():
    flat = array.array("H", [BACKGROUND_COUNTS] * (WIDTH * HEIGHT))  # ties everywhere
    zero = array.array("H", [0] * (WIDTH * HEIGHT))  # below background
    sat = array.array("H", [BACKGROUND_COUNTS] * (WIDTH * HEIGHT))  # saturated patches
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
        out += frame(msg_pixel_rows(frame_id, first // 2, raw[first : first + step]))
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
    "canary": (
        dict(rule="subtract-next", n=20),
        '[selection]\nrule = "subtract-next"\npixels = 20\n',
        "",
    ),
    "mean": (
        dict(rule="subtract-mean", n=12, mean_count=4, level_filter=3, threshold=16),
        '[selection]\nrule = "subtract-mean"\nmean_count = 4\npixels = 12\n'
        "[selection.level_filter]\ngain_shift = 3\n",
        "threshold_counts = 1.0\n",
    ),
}


def toml_for(name):
    _, selection, calibration = CONFIGS[name]
    return (
        f"[camera]\nwidth = {WIDTH}\nheight = {HEIGHT}\nbit_depth = 16\n\n"
        f"[subapertures.grid]\nx = 0\ny = 0\ncolumns = {ACROSS}\nrows = {ACROSS}\n"
        f"width = {SIDE}\nheight = {SIDE}\n\n"
        f"[calibration]\nbackground_counts = {BACKGROUND_COUNTS}\n{calibration}\n{selection}\n"
        "[centroid]\nmin_flux_counts = 0.0\n"
    )


def upload(dev, upload_id, name):
    header, _, _ = CONFIGS[name]
    tables = [(TABLE_WINDOWS, windows_table()), (TABLE_BACKGROUND, background_table())]
    begin = msg_config_begin(
        upload_id, width=WIDTH, height=HEIGHT, windows=ACROSS * ACROSS, background=True, **header
    )
    reply = dev.request(begin)
    assert reply == ("Ack", dict(ack="UploadStarted", value=upload_id)), reply
    # The commit's CRC is the configuration's digest: the header, then the tables.
    crc = zlib.crc32(config_header_of(begin))
    for table, data in tables:
        for off in range(0, len(data), CHUNK_BYTES):
            part = data[off : off + CHUNK_BYTES]
            crc = zlib.crc32(part, crc)
            kind, f = dev.request(msg_config_chunk(upload_id, table, off, part))
            assert kind == "Ack" and f["ack"] == "ChunkStored" and f["end"] == off + len(part), (
                kind,
                f,
            )
    return dev.request(msg_config_commit(upload_id, crc))


def write_npy_u16(path, frames):
    shape = f"({len(frames)}, {HEIGHT}, {WIDTH})"
    header = "{'descr': '<u2', 'fortran_order': False, 'shape': " + shape + ", }"
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
    header = data[start : start + hlen].decode()
    descr = re.search(r"'descr': '([^']+)'", header).group(1)
    shape = tuple(
        int(x) for x in re.search(r"'shape': \(([^)]*)\)", header).group(1).split(",") if x.strip()
    )
    code = {"<f8": "d", "|u1": "B", "<u1": "B"}[descr]
    arr = array.array(code, data[start + hlen :])
    return shape, arr


def host_results(brightpix, tmp, name, frames, reference):
    cfg = os.path.join(tmp, f"{name}.toml")
    with open(cfg, "w") as f:
        f.write(toml_for(name))
    frames_path = os.path.join(tmp, f"{name}-frames.npy")
    write_npy_u16(frames_path, frames)
    out = os.path.join(tmp, "{}-slopes{}.npy".format(name, "-ref" if reference else ""))
    valid = out.replace(".npy", "-valid.npy")
    cmd = [
        brightpix,
        "process",
        "--config",
        cfg,
        "--frames",
        frames_path,
        "--out",
        out,
        "--valid-out",
        valid,
    ]
    if reference:
        cmd.append("--reference")
    subprocess.run(cmd, check=True, capture_output=True)
    shape, slopes = read_npy(out)
    _, valid_flags = read_npy(valid)
    n = ACROSS * ACROSS
    assert shape == (len(frames), n, 2), shape
    return [
        [
            (slopes[(k * n + s) * 2], slopes[(k * n + s) * 2 + 1], valid_flags[k * n + s])
            for s in range(n)
        ]
        for k in range(len(frames))
    ]


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
    check(
        not mismatches,
        f"{what}: {len(frame_ids)} frames x {len(expected[0]) if expected else 0} "
        "sub-apertures bit-exact"
        + ("" if not mismatches else f"; first mismatches: {mismatches[:3]!r}"),
    )


def write_pixels(path, data):
    """One batch of PixelRows frames into the FIFO: open, write, close. While the FIFO is
    open for writing and empty, the device blocks in its read (UART0 too). A regular file
    is appended to."""
    fd = os.open(path, os.O_WRONLY | (0 if stat.S_ISFIFO(os.stat(path).st_mode) else os.O_APPEND))
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
    finally:
        os.close(fd)


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what, flush=True)
    if not cond:
        check.failed = True


check.failed = False


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--vectors",
        action="store_true",
        help="only check this client against shared/protocol-vectors.json (no QEMU)",
    )
    ap.add_argument("--elf", default=DEFAULT_ELF)
    ap.add_argument("--brightpix", default=DEFAULT_BRIGHTPIX)
    ap.add_argument("--uart-frames", type=int, default=4)
    ap.add_argument("--fifo-frames", type=int, default=200)
    ap.add_argument(
        "--regular-file",
        action="store_true",
        help="give --pixels a regular file that the host appends to, not a FIFO",
    )
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
            check(
                kind == "HelloReply" and f["version"] == version and f["schema"] == schema,
                f"Hello -> HelloReply, protocol {f.get('version')}, schema {f.get('schema'):#x} "
                f"({time.monotonic() - t0:.2f} s after QEMU start)",
            )
            caps = f["capabilities"]
            print(f"     capabilities: {caps}")
            check(
                caps["board"] == "qemu-mps2-an386" and caps["pixel_source"] == "Stream",
                "board qemu-mps2-an386, pixel source Stream",
            )

            t = time.monotonic()
            kind, f = upload(dev, 1, "canary")
            check(
                kind == "Ack" and f["ack"] == "ConfigApplied" and f["config_id"] == 1,
                "CANARY configuration uploaded (windows + 50 KB background map) in "
                f"{time.monotonic() - t:.2f} s: {f}",
            )

            order = []  # (config name, frame id, pixels) in device order
            # --- PixelRows over UART0 ---
            uart = [spot_frame(rng) for _ in range(opts.uart_frames)]
            ids = list(range(1, 1 + len(uart)))
            data = b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, uart))
            t = time.monotonic()
            dev.sock.sendall(data)
            dev.wait_frames(ids, timeout=60 + 5 * len(ids))
            dt = time.monotonic() - t
            uart_rate = len(ids) / dt
            check(
                True,
                f"UART0 path: {len(ids)} frames in {dt:.2f} s: {uart_rate:.2f} frames/s "
                f"({len(data) / dt / 1e3:.1f} KB/s of PixelRows)",
            )
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
            check(
                kind == "Status" and 0 < f["frames_processed"] < len(order) + len(ids),
                f"StatusRequest during the stream answered in {status_rtt * 1e3:.1f} ms "
                f"({f.get('frames_processed', -1)} frames processed by then)",
            )
            fifo_rate = len(ids) / dt
            check(
                True,
                f"FIFO path: {len(ids)} frames in {dt:.2f} s: {fifo_rate:.1f} frames/s "
                f"({len(data) / dt / 1e3:.0f} KB/s of PixelRows in, Slopes out on UART0); "
                f"QEMU used {cpu / len(ids) * 1e3:.2f} ms of CPU per frame "
                f"({len(ids) / max(cpu, 1e-3):.0f} frames/s if it had a core to itself)",
            )
            order += [("canary", i, px) for i, px in zip(ids, fifo_frames)]

            # --- the FIFO is closed: UART0 must answer at once; reopen and stream again ---
            time.sleep(0.2)
            rtts = []
            for _ in range(5):
                t = time.monotonic()
                kind, f = dev.request(msg_status_request(), timeout=5)
                rtts.append(time.monotonic() - t)
            check(
                kind == "Status",
                "FIFO closed by the host: StatusRequest answered in %.1f ms (median of 5)"
                % (sorted(rtts)[2] * 1e3),
            )
            more = [spot_frame(rng) for _ in range(5)]
            ids = list(range(2001, 2001 + len(more)))
            write_pixels(pixels, b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, more)))
            dev.wait_frames(ids, timeout=30)
            check(True, f"FIFO reopened: {len(ids)} more frames processed")
            order += [("canary", i, px) for i, px in zip(ids, more)]

            # --- a corrupted frame on the link ---
            bad = bytearray(frame(msg_status_request()))
            bad[1] ^= 0x40
            dev.sock.sendall(bytes(bad))
            kind, f = dev.replies.get(timeout=10)
            check(
                kind == "Error" and f["error"] == "Crc",
                f"corrupted frame answered with Error(Crc): {f}",
            )

            # --- a second configuration, more frames through the FIFO ---
            kind, f = upload(dev, 2, "mean")
            check(
                kind == "Ack" and f["ack"] == "ConfigApplied" and f["config_id"] == 2,
                f"second configuration (subtract-mean M=4 N=12, threshold, level filter): {f}",
            )
            mean = [spot_frame(rng) for _ in range(20)]
            ids = list(range(3001, 3001 + len(mean)))
            write_pixels(pixels, b"".join(pixel_rows_frames(i, px) for i, px in zip(ids, mean)))
            dev.wait_frames(ids, timeout=30)
            order += [("mean", i, px) for i, px in zip(ids, mean)]

            kind, status = dev.request(msg_status_request())
            n_frames = len(order)
            check(
                kind == "Status"
                and status["frames_processed"] == n_frames
                and status["crc_errors"] == 1
                and status["frames_dropped"] == 0
                and status["decode_errors"] == 0
                and status["overruns"] == 0
                and status["config_id"] == 2,
                f"Status: {status}",
            )
            check(
                [e for e in dev.errors if e.get("error") != "Crc"] == [],
                f"no other errors from the device: {dev.errors}",
            )
        finally:
            dev.close()

        # --- the host's engine and reference on the same frames ---
        for name in ("canary", "mean"):
            frames = [px for (c, _, px) in order if c == name]
            ids = [i for (c, i, _) in order if c == name]
            for reference in (False, True):
                expected = host_results(opts.brightpix, tmp, name, frames, reference)
                compare(
                    dev,
                    ids,
                    expected,
                    f"{name} vs host {'reference' if reference else 'engine (HostEngine)'}",
                )

        print("     device log:")
        for line in dev.defmt_lines(elf)[1]:
            print("       " + line)
    print(
        f"     throughput: UART0 PixelRows {uart_rate:.2f} frames/s, FIFO {fifo_rate:.1f} frames/s"
    )
    print("FAILED" if check.failed else "all checks passed")
    return 1 if check.failed else 0


if __name__ == "__main__":
    sys.exit(main())
