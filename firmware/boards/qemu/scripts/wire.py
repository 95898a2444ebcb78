#!/usr/bin/env python3
"""brightpix's wire format (shared/PROTOCOL.md) in Python, standard library only.

An implementation of its own, written from PROTOCOL.md and not from the Rust crate, so that
it checks the document as much as the firmware: COBS framing with CRC-32, postcard varints,
the host messages the QEMU check sends and every device message decoded to a dict.

`python3 wire.py` checks it against shared/protocol-vectors.json (the Rust test
`the_python_client_agrees_with_the_vectors` runs it, through `check_device.py --vectors`).
Used by check_device.py, the end-to-end check of the QEMU device.
"""

import json
import os
import re
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.normpath(os.path.join(HERE, "..", "..", "..", ".."))


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
        out += data[i + 1 : i + code]
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
        v = self.b[self.i : self.i + n]
        self.i += n
        return bytes(v)

    def rest(self):
        return self.b[self.i :]


# HostMessage
def msg_hello(version, schema, session=0xC4EC):
    return bytes([0]) + varint(version) + varint(schema) + varint(session)


RULES = {"threshold": (0,), "subtract-next": (1,), "subtract-next-distinct": (2,)}


def msg_config_begin(
    upload_id,
    *,
    width,
    height,
    rule,
    n,
    mean_count=None,
    level_filter=None,
    threshold=None,
    min_flux=0,
    windows,
    background,
    gain=False,
    reference_slopes=False,
):
    rule_bytes = (
        varint(3) + varint(mean_count) if rule == "subtract-mean" else varint(RULES[rule][0])
    )
    header = (
        varint(width)
        + varint(height)
        + bytes([16])  # camera
        + varint(windows)
        + rule_bytes
        + varint(0)
        + varint(n)  # PixelCountMode::All(n)
        + (bytes([1, level_filter]) if level_filter is not None else b"\x00")
        + (b"\x01" + zigzag(threshold) if threshold is not None else b"\x00")
        + zigzag(min_flux)
        # Background: 0 None, 1 Map (a table follows), 2 Constant(i32)
        + bytes([background, gain, reference_slopes])
        + b"\x00"
    )  # crop: None, the camera is the whole sensor

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
ACKS = [
    "UploadStarted",
    "ChunkStored",
    "ConfigApplied",
    "UploadAborted",
    "LevelFiltersReset",
    "CaptureStarted",
    "CaptureStopped",
    "BenchDone",
    "LinkTestDone",
]
ERRORS = [
    "Decode",
    "Crc",
    "FrameTooLong",
    "HelloRequired",
    "Unexpected",
    "NoUpload",
    "UploadMismatch",
    "ChunkOutOfOrder",
    "ChunkLength",
    "ChunkPastEnd",
    "UploadIncomplete",
    "UploadCrc",
    "Capacity",
    "Config",
    "NotConfigured",
    "Frame",
    "NoCamera",
    "Crop",
    "Bench",
    "Sync",
    "LinkTest",
]
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
        caps = dict(
            max_subapertures=r.varint(),
            max_camera_pixels=r.varint(),
            max_open_windows=r.varint(),
            pool_entries=r.varint(),
            history_pixels=r.varint(),
            scratch_entries=r.varint(),
            max_results_per_row=r.varint(),
            max_frame_bytes=r.varint(),
            pixel_source=SOURCES[r.varint()],
            board=r.bytes().decode(),
        )
        return "HelloReply", dict(
            version=version, schema=schema, session=session, capabilities=caps
        )
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
        elif name == "LinkTestDone":
            f = dict(bytes=r.varint(), messages=r.varint())
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
        return "Status", dict(
            config_id=r.option(r.varint),
            upload_id=r.option(r.varint),
            capturing=r.bool(),
            frames_processed=r.varint(),
            frames_dropped=r.varint(),
            crc_errors=r.varint(),
            decode_errors=r.varint(),
            overruns=r.varint(),
            pixel_errors=r.varint(),
            session=r.option(r.varint),
            reset_reason=r.varint(),
            watchdog_ms=r.option(r.varint),
            health=decode_health(r),
            config_digest=r.option(r.varint),
            engine=dict(
                windows=r.varint(),
                candidates=r.varint(),
                compactions=r.varint(),
                rescans=r.varint(),
                attentions=r.varint(),
                kernel_frames=r.varint(),
            ),
        )
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
    if kind == 9:
        # A link test's fill (PROTOCOL.md §15): byte k is (offset + k) % 251.
        return "LinkFill", dict(offset=r.varint(), fill=list(r.bytes()))
    raise ValueError(f"unknown device message {kind}")


def decode_bench_report(r):
    """BenchReport (PROTOCOL.md §14), as serde's JSON of it."""

    def spread():
        return dict(min=r.varint(), median=r.varint(), max=r.varint())

    report = dict(
        workload=r.bytes().decode(),
        unit=COUNT_UNITS[r.varint()],
        clock_hz=r.option(r.varint),
        pixels=r.varint(),
        frames=r.varint(),
    )
    variant = r.varint()
    if variant == 0:
        result = {
            "Measured": dict(
                engine_total=r.varint(),
                engine_frame=spread(),
                engine_last_row=spread(),
                floor_total=r.varint(),
                floor_frame=spread(),
                floor_last_row=spread(),
                floor_check=FLOOR_CHECKS[r.varint()],
            )
        }
    elif variant == 1:
        result = {"DoesNotFit": dict(limit=BENCH_LIMITS[r.varint()])}
    elif variant == 2:
        result = {"SlopesDiffer": dict(window=r.varint())}
    else:
        raise ValueError(f"unknown bench result {variant}")
    report["result"] = result
    if r.rest():
        raise ValueError("bytes after a BenchReport")
    return report


def decode_health(r):
    """Status.health (PROTOCOL.md §5): seven options; u8 is one byte, wider
    integers are varints."""
    silicon = r.option(
        lambda: dict(device_id=r.varint(), revision_id=r.varint(), axi_sram_fix=r.varint())
    )
    clocks = r.option(
        lambda: dict(
            sysclk_configured_hz=r.varint(),
            sysclk_read_hz=r.varint(),
            voltage_scale_configured=r.u8(),
            voltage_scale_read=r.u8(),
            voltage_ready=r.bool(),
        )
    )
    usb_clock = r.option(
        lambda: dict(sync_source=r.u8(), synced=r.bool(), trim=r.u8(), sync_errors=r.varint())
    )
    stack = r.option(lambda: dict(size=r.varint(), peak=r.varint(), guarded=r.bool()))
    camera = r.option(
        lambda: dict(
            overruns=r.varint(),
            sync_errors=r.varint(),
            dma_transfer_errors=r.varint(),
            dma_fifo_errors=r.varint(),
            fifo_not_drained=r.varint(),
        )
    )
    idle = r.option(r.varint)

    def fault():
        return dict(
            kind=["HardFault"][r.varint()],
            pc=r.varint(),
            lr=r.varint(),
            cfsr=r.varint(),
            hfsr=r.varint(),
            mmfar=r.varint(),
            bfar=r.varint(),
        )

    faults = r.option(lambda: dict(before_reset=r.option(fault)))
    return dict(
        silicon=silicon,
        clocks=clocks,
        usb_clock=usb_clock,
        stack=stack,
        camera_interface=camera,
        idle_permille=idle,
        faults=faults,
    )


def schema_from_protocol_md():
    """The protocol version and schema hash PROTOCOL.md states."""
    with open(os.path.join(REPO, "shared", "PROTOCOL.md")) as f:
        text = f.read()
    version = int(re.search(r"wire protocol, version (\d+)", text).group(1))
    schema = int(
        re.search(r"Schema hash of this document's messages: \*\*`(0x[0-9a-f]+)`", text).group(1),
        16,
    )
    return version, schema


def check_vectors():
    """This client against shared/protocol-vectors.json: every device frame
    unframes to its body and decodes to the vector's message kind (and, for
    HelloReply and Status, to its fields); the Hello this script sends
    encodes to the vector's bytes."""
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
                assert (
                    msg_hello(h["protocol"]["version"], h["protocol"]["schema"], h["session"])
                    == body
                ), v
                assert frame(body) == bytes.fromhex(v["frame"]), v
            continue
        kind, fields = decode_device(body)
        expected = message if isinstance(message, str) else next(iter(message))
        assert kind == expected, (kind, v["name"])
        if kind == "HelloReply":
            h = message["HelloReply"]
            assert (fields["version"], fields["schema"], fields["session"]) == (
                h["version"],
                h["schema"],
                h["session"],
            ), v["name"]
            assert fields["capabilities"]["board"] == h["capabilities"]["board"]
        if kind == "Status":
            st = message["Status"]
            for key in (
                "frames_processed",
                "crc_errors",
                "session",
                "watchdog_ms",
                "config_digest",
                "engine",
            ):
                assert fields[key] == st[key], (key, fields, st)
            health = dict(st["health"])
            if health["silicon"] is not None:
                fix = health["silicon"]["axi_sram_fix"]
                health["silicon"] = dict(health["silicon"], axi_sram_fix=ERRATUM_FIXES.index(fix))
            assert fields["health"] == health, (fields["health"], health)
        if kind in ("BenchReport", "CaptureBegan", "EdgeRows", "LinkFill"):
            assert fields == message[kind], (fields, message)
        if kind == "LinkFill":
            offset = fields["offset"]
            assert fields["fill"] == [(offset + k) % 251 for k in range(len(fields["fill"]))]
        count += 1
    print(
        f"vectors: {count} device messages decoded and the Hello encoded as in "
        "shared/protocol-vectors.json"
    )


if __name__ == "__main__":
    check_vectors()
