"""The QEMU device as the check scripts run it: the firmware ELF on the mps2-an386 board
(Cortex-M4), UART0 on a unix socket that QEMU waits for, QEMU's stdout (the semihosting
output: defmt frames, nothing else with -display/-monitor none) in a file, and the
semihosting command line as firmware/boards/qemu/README.md describes it. Standard library
only; used by check_device.py and check_qemu.py.
"""

import os
import signal
import socket
import subprocess
import time


def command(elf, serial, args=()):
    """qemu-system-arm's command line for `elf` with UART0 on `serial` (a QEMU character
    device: `pty`, `unix:PATH,server=on,wait=on`) and `args` after the program name on the
    semihosting command line."""
    semihosting = "".join(",arg=" + a for a in ("brightpix-qemu", *args))
    return [
        "qemu-system-arm",
        "-cpu",
        "cortex-m4",
        "-machine",
        "mps2-an386",
        "-display",
        "none",
        "-monitor",
        "none",
        "-serial",
        serial,
        "-semihosting-config",
        "enable=on,target=native" + semihosting,
        "-kernel",
        elf,
    ]


class Qemu:
    """QEMU running `elf` with `args` after the program name on the semihosting command
    line (e.g. `["--pixels", path]`); connected to UART0 (`sock`) when built."""

    def __init__(self, elf, tmp, args=()):
        self.sock_path = os.path.join(tmp, "uart0.sock")
        self.log_path = os.path.join(tmp, "defmt.bin")
        for p in (self.sock_path, self.log_path):
            if os.path.exists(p):
                os.unlink(p)
        cmd = command(elf, f"unix:{self.sock_path},server=on,wait=on", args)
        self.t0 = time.monotonic()
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while True:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self.sock.connect(self.sock_path)
                break
            except (FileNotFoundError, ConnectionRefusedError) as err:
                self.sock.close()
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise RuntimeError(
                        f"QEMU did not open the UART socket: {self.proc.communicate()!r}"
                    ) from err
                time.sleep(0.02)
        self.t_connected = time.monotonic()

    def recv_exact(self, n, timeout=10.0):
        self.sock.settimeout(timeout)
        out = bytearray()
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise RuntimeError(f"UART socket closed after {len(out)} of {n} bytes")
            out += chunk
        return bytes(out)

    def wait(self, timeout=10.0):
        """Waits for the firmware to exit; its exit code."""
        rc = self.proc.wait(timeout)
        self.t_exit = time.monotonic()
        self.sock.close()
        self.log.close()
        return rc

    def stop(self):
        """Ends QEMU (SIGTERM, then SIGKILL after 5 s)."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.sock.close()
        self.log.close()

    def cpu_seconds(self):
        """Host CPU time QEMU has used so far."""
        with open(f"/proc/{self.proc.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def defmt_lines(self, elf):
        """The raw defmt log so far and its lines decoded by defmt-print (one line saying
        so if defmt-print is not on PATH)."""
        with open(self.log_path, "rb") as f:
            raw = f.read()
        try:
            res = subprocess.run(
                ["defmt-print", "-e", elf], input=raw, capture_output=True, timeout=30
            )
        except (FileNotFoundError, subprocess.TimeoutExpired):
            return raw, ["(defmt-print not available)"]
        text = res.stdout.decode(errors="replace") + res.stderr.decode(errors="replace")
        return raw, [line for line in text.splitlines() if line.strip()]
