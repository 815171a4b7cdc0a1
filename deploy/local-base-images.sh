#!/usr/bin/env bash
# Builds the two base images deploy/Containerfile starts from, locally, for a
# machine that can reach Debian's package mirrors and crates.io but no
# container registry (docker.io is unreachable there, so `FROM debian:...`
# and `FROM rust:...` cannot be pulled):
#
#   localhost/debian:bookworm-slim  a debootstrap'ed Debian 12 (minbase)
#   localhost/rust:1-bookworm       that, plus gcc/pkg-config and the Rust
#                                   toolchain this machine builds with
#                                   (copied from `rustc --print sysroot`,
#                                   without its documentation), trusting
#                                   the extra CAs this machine trusts
#                                   (/usr/local/share/ca-certificates: a
#                                   TLS-intercepting egress proxy's CA, so
#                                   that cargo can reach crates.io)
#
# Then build with (see deploy/README.md):
#   podman build --isolation chroot --network host \
#     --build-arg RUST_IMAGE=localhost/rust:1-bookworm \
#     --build-arg RUNTIME_IMAGE=localhost/debian:bookworm-slim \
#     -f deploy/Containerfile -t lightwire:dev .
#
# Needs root, podman, debootstrap (Debian packages `podman`, `debootstrap`).
# Idempotent: an image that exists is kept (pass --force to rebuild).
set -euo pipefail

MIRROR=${MIRROR:-http://deb.debian.org/debian}
force=0
[ "${1:-}" = "--force" ] && force=1

have() { podman image exists "$1" && [ "$force" = 0 ]; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

if have localhost/debian:bookworm-slim; then
  echo "localhost/debian:bookworm-slim exists"
else
  echo "debootstrap bookworm (minbase) from $MIRROR ..."
  debootstrap --variant=minbase bookworm "$work/rootfs" "$MIRROR" >"$work/debootstrap.log" 2>&1 ||
    { tail -20 "$work/debootstrap.log"; exit 1; }
  # What the official slim image also drops: package lists and caches.
  rm -rf "$work/rootfs/var/lib/apt/lists/"* "$work/rootfs/var/cache/apt/"*.bin
  tar -C "$work/rootfs" -c . | podman import --change 'CMD ["bash"]' - localhost/debian:bookworm-slim
  rm -rf "$work/rootfs"
fi

if have localhost/rust:1-bookworm; then
  echo "localhost/rust:1-bookworm exists"
else
  sysroot=$(rustc --print sysroot)
  echo "Rust image from $sysroot ($(rustc --version))"
  mkdir -p "$work/ctx/rust" "$work/ctx/ca"
  cp -a "$sysroot/bin" "$sysroot/lib" "$work/ctx/rust/"
  cp /usr/local/share/ca-certificates/*.crt "$work/ctx/ca/" 2>/dev/null || true
  cat >"$work/ctx/Containerfile" <<'INNER'
FROM localhost/debian:bookworm-slim
RUN apt-get update -q && \
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
      ca-certificates gcc libc6-dev pkg-config && \
    rm -rf /var/lib/apt/lists/*
COPY ca /usr/local/share/ca-certificates
RUN update-ca-certificates
COPY rust /usr/local/rust
ENV PATH=/usr/local/rust/bin:$PATH CARGO_HOME=/usr/local/cargo
RUN rustc --version && cargo --version
INNER
  podman build --isolation chroot --network host -t localhost/rust:1-bookworm "$work/ctx"
fi
