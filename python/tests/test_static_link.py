"""The extension module needs no system FITS library: cfitsio is compiled in statically
(host/Cargo.toml), so `pip install ./python` and a built wheel work without libcfitsio."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

import brightpix._brightpix as extension


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ldd is glibc's loader listing")
def test_extension_links_no_fits_curl_or_tls_library() -> None:
    if shutil.which("ldd") is None:
        pytest.skip("ldd is not installed")
    listing = subprocess.run(
        ["ldd", extension.__file__], check=True, capture_output=True, text=True
    ).stdout
    assert "libc.so" in listing, listing
    for library in ("cfitsio", "curl", "gnutls", "libz.so"):
        assert library not in listing, listing
