#!/bin/bash
# Builds the `chaoscope` binary for 64-bit ARM (aarch64 Linux: NEON, no x86 vector path) and
# checks that it runs under user-mode QEMU, for tests/aarch64_bit_identical.rs. Installs what is
# missing: Debian's cross linker (gcc-aarch64-linux-gnu, which also brings the ARM C library the
# emulator loads) and qemu-user with apt-get (needs root then), and Rust's aarch64 standard
# library with rustup.
#
#   tests/aarch64/build.sh      # then: cargo test --release --test aarch64_bit_identical -- --ignored
#
# The binary lands in <target dir>/aarch64-unknown-linux-gnu/release/chaoscope, where the test
# looks for it. Built without debug info: nobody profiles it, and linking is faster.
set -euo pipefail
cd "$(dirname "$0")/../.."

TARGET=aarch64-unknown-linux-gnu

if ! command -v aarch64-linux-gnu-gcc >/dev/null || ! command -v qemu-aarch64 >/dev/null; then
    if [[ $(id -u) -ne 0 ]]; then
        echo "build.sh: gcc-aarch64-linux-gnu and qemu-user are missing; install them as root" >&2
        exit 1
    fi
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q >/dev/null
    apt-get install -y -q gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user >/dev/null
fi

if ! rustup target list --installed | grep -qx "$TARGET"; then
    rustup target add "$TARGET"
fi

export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
export CC_aarch64_unknown_linux_gnu=aarch64-linux-gnu-gcc
export AR_aarch64_unknown_linux_gnu=aarch64-linux-gnu-ar
CARGO_PROFILE_RELEASE_DEBUG=false cargo build --release --target "$TARGET" --bin chaoscope

target_dir=$(cargo metadata --format-version 1 --no-deps \
    | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
bin="$target_dir/$TARGET/release/chaoscope"
QEMU_LD_PREFIX=/usr/aarch64-linux-gnu qemu-aarch64 "$bin" --version
file "$bin" 2>/dev/null || true
