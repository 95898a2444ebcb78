//! The README's first command must work on a machine with only rustup and a
//! C compiler: cfitsio is compiled from source and linked statically, so the
//! binary needs no FITS, curl or TLS library at run time (and resolves none
//! of their symbols at every start).

#[cfg(target_os = "linux")]
#[test]
fn binary_links_no_fits_curl_or_tls_library() {
    let binary = env!("CARGO_BIN_EXE_brightpix");
    let out = std::process::Command::new("ldd")
        .arg(binary)
        .output()
        .expect("ldd (glibc's loader listing) runs");
    assert!(out.status.success(), "ldd {binary} failed: {out:?}");
    let listing = String::from_utf8_lossy(&out.stdout);
    assert!(
        listing.contains("libc.so"),
        "ldd lists no libc, so this test could not see a library: {listing}"
    );
    for library in ["cfitsio", "curl", "gnutls", "libz.so"] {
        assert!(
            !listing.contains(library),
            "{binary} links {library} dynamically:\n{listing}"
        );
    }
}
