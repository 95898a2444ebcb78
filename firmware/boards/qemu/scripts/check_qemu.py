#!/usr/bin/env python3
"""Board checks of the brightpix QEMU firmware, in its echo self-test mode
(`selftest=echo` on the semihosting command line): run it under QEMU and check

1. UART0 echo: random bytes come back unchanged (bulk and single-byte round trips);
   byte 0x04 ends the emulation with exit code 0;
2. defmt over semihosting decodes (defmt-print) and has the expected lines,
   including the semihosting file-read smoke check (`--digest PATH`: length + FNV-1a of a
   host file);
3. the device clock (SysTick, 25 MHz) roughly matches wall time (QEMU without -icount);
4. the idle executor sleeps (WFI): little host CPU while waiting for input;
5. panic and HardFault (UDF) end QEMU with exit codes 101 and 102.

The device itself (protocol, pixel FIFO, slopes against the host) is checked by
check_device.py.

Usage: check_qemu.py [ELF]   (default: firmware/target/thumbv7em-none-eabihf/release/brightpix-qemu)
Needs qemu-system-arm and defmt-print (cargo install defmt-print) on PATH.
"""

import os
import random
import re
import select
import subprocess
import sys
import tempfile
import threading
import time
import tty

from qemu import Qemu, command

HERE = os.path.dirname(os.path.abspath(__file__))
FIRMWARE = os.path.normpath(os.path.join(HERE, "..", "..", ".."))
DEFAULT_ELF = os.path.join(FIRMWARE, "target", "thumbv7em-none-eabihf", "release", "brightpix-qemu")
EOT = 0x04
PTY_BYTES = int(os.environ.get("PTY_BYTES", 100_000))
PTY_DELAY = float(os.environ.get("PTY_DELAY", 3.0))


def fnv1a32(data):
    h = 0x811C9DC5
    for b in data:
        h = ((h ^ b) * 0x01000193) & 0xFFFFFFFF
    return h


def pty_backpressure(elf, tmp, payload, delay):
    """UART0 on a pty that the host does not read for `delay` s while it sends `payload`:
    the device's TX stalls (pty buffer full), so it stops reading, so its RX FIFO fills
    and the RX interrupt must hold QEMU off. Everything must still arrive, in order.
    Returns (echo ok, exit code, defmt lines)."""
    log_path = os.path.join(tmp, "defmt-pty.bin")
    log = open(log_path, "wb")
    cmd = command(elf, "pty", ["selftest=echo"])
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.PIPE)
    pts = None
    deadline = time.monotonic() + 10
    while pts is None and time.monotonic() < deadline:
        with open(log_path, "rb") as f:
            m = re.search(rb"(/dev/pts/\d+)", f.read(200))
        pts = m and m.group(1).decode()
        time.sleep(0.02)
    fd = os.open(pts, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)

    def read_avail(timeout):
        out = b""
        while select.select([fd], [], [], timeout)[0]:
            out += os.read(fd, 65536)
            timeout = 0.05
        return out

    # QEMU notices the pty client within ~1 s; bytes sent before are lost.
    for _ in range(20):
        os.write(fd, b"S")
        if b"S" in read_avail(0.5):
            break
    read_avail(1.2)  # drain late echoes of retries

    def writer():
        view = memoryview(payload)
        while view:
            n = os.write(fd, view[:4096])
            view = view[n:]

    th = threading.Thread(target=writer)
    th.start()
    time.sleep(delay)
    got = bytearray()
    end = time.monotonic() + 120
    while len(got) < len(payload) and time.monotonic() < end:
        if select.select([fd], [], [], 1.0)[0]:
            got += os.read(fd, 65536)
    th.join()
    os.write(fd, bytes([EOT]))
    rc = proc.wait(10)
    os.close(fd)
    log.close()
    with open(log_path, "rb") as f:
        raw = f.read()
    raw = raw[raw.index(b")\n") + 2 :]  # QEMU's "char device redirected to ..." line
    res = subprocess.run(["defmt-print", "-e", elf], input=raw, capture_output=True, timeout=30)
    lines = [line for line in res.stdout.decode(errors="replace").splitlines() if line.strip()]
    return bytes(got) == payload, rc, lines


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what)
    if not cond:
        check.failed = True


check.failed = False


def main():
    elf = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else DEFAULT_ELF)
    rng = random.Random(1)
    with tempfile.TemporaryDirectory() as tmp:
        # --- main run: hostfs smoke file, idle CPU, echo, EOT ---
        blob = bytes(rng.randrange(256) for _ in range(100_000))
        blob_path = os.path.join(tmp, "smoke.bin")
        with open(blob_path, "wb") as f:
            f.write(blob)
        q = Qemu(elf, tmp, ["selftest=echo", "--digest", blob_path])

        # Wait for the echo loop to be up: one byte round trip.
        q.sock.sendall(b"A")
        check(q.recv_exact(1, timeout=10) == b"A", "first echo byte")

        cpu0, w0 = q.cpu_seconds(), time.monotonic()
        time.sleep(2.0)
        cpu = q.cpu_seconds() - cpu0
        idle_wall = time.monotonic() - w0
        check(
            cpu < 0.5 * idle_wall,
            f"idle: {cpu:.2f} s host CPU in {idle_wall:.2f} s wall (WFI sleeps)",
        )

        rtts = []
        for i in range(50):
            b = bytes([0x30 + i % 10])
            t = time.monotonic()
            q.sock.sendall(b)
            got = q.recv_exact(1)
            rtts.append(time.monotonic() - t)
            if got != b:
                check(False, f"single-byte echo {i}: sent {b!r} got {got!r}")
                break
        rtts.sort()
        print(
            f"     single-byte round trip: median {rtts[len(rtts) // 2] * 1e6:.0f} us, "
            f"max {rtts[-1] * 1e6:.0f} us"
        )

        payload = bytes(rng.choice([b for b in range(256) if b != EOT]) for _ in range(32_768))
        received = bytearray()

        def reader():
            received.extend(q.recv_exact(len(payload), timeout=60))

        th = threading.Thread(target=reader)
        t = time.monotonic()
        th.start()
        q.sock.sendall(payload)
        th.join()
        dt = time.monotonic() - t
        check(
            bytes(received) == payload,
            f"bulk echo of {len(payload)} random bytes "
            f"({len(payload) / dt / 1e3:.1f} KB/s each way)",
        )

        q.sock.sendall(bytes([EOT]))
        rc = q.wait()
        wall = q.t_exit - q.t0
        check(rc == 0, f"EOT ends QEMU with exit code 0 (got {rc})")

        raw, lines = q.defmt_lines(elf)
        print(f"     defmt log ({len(raw)} bytes raw):")
        for line in lines:
            print("       " + line)
        text = "\n".join(lines)
        check("brightpix-qemu: qemu-mps2-an386" in text, "defmt hello decoded")
        m = re.search(r"timer: 10 ms took (\d+) us", text)
        check(
            m is not None and 10_000 <= int(m.group(1)) <= 20_000,
            "Timer::after_millis(10) took [10, 20] ms (QEMU without -icount follows host time)",
        )
        want = f"{len(blob)} bytes read (SYS_FLEN {len(blob)}), fnv1a32 0x{fnv1a32(blob):08x}"
        check(want in text, "hostfs smoke check: " + want)
        total = 1 + 50 + len(payload)
        check(f"EOT after {total} bytes echoed" in text, f"device counted {total} echoed bytes")
        stamps = [int(x) for x in re.findall(r"^(\d+) ", text, re.M)]
        if not stamps:
            stamps = [int(float(x) * 1e6) for x in re.findall(r"^(\d+\.\d+) ", text, re.M)]
        if stamps:
            dev = stamps[-1] / 1e6
            check(
                0.7 * wall - 0.3 < dev < wall + 0.3,
                f"device clock: last log at {dev:.2f} s, wall {wall:.2f} s from QEMU start",
            )
        else:
            check(False, "defmt timestamps found")

        # --- flow control both ways (pty the host stops reading) ---
        payload = bytes(rng.choice([b for b in range(256) if b != EOT]) for _ in range(PTY_BYTES))
        ok, rc, lines = pty_backpressure(elf, tmp, payload, PTY_DELAY)
        m = re.search(r"rx_stalls: (\d+), tx_waits: (\d+)", "\n".join(lines))
        stalls, waits = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
        check(
            ok and rc == 0,
            f"pty, host reads only after {PTY_DELAY:.1f} s: {len(payload)} bytes echoed intact, "
            f"exit {rc}",
        )
        check(
            stalls > 0 and waits > 0,
            f"flow control exercised: RX stalls {stalls}, TX waits {waits}",
        )

        # --- failure paths ---
        for arg, code, needle in (
            ("selftest=panic", 101, "panic"),
            ("selftest=udf", 102, "HardFault"),
        ):
            q = Qemu(elf, tmp, [arg])
            rc = q.wait()
            _, lines = q.defmt_lines(elf)
            check(
                rc == code and any(needle in line for line in lines),
                f"{arg}: exit code {rc} (want {code}), log: {lines[-1] if lines else '-'}",
            )

    print("FAILED" if check.failed else "all checks passed")
    return 1 if check.failed else 0


if __name__ == "__main__":
    sys.exit(main())
