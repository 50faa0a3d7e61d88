#!/usr/bin/env bash
# Build a local Debian bookworm base image with python3 (venv, pip) from Debian's own packages, for machines
# where Docker Hub (python:3.11-slim) cannot be reached:
#
#     scripts/make_base_image.sh [TAG]          # default tag: ncs-design-base:bookworm
#     docker build --network host --build-arg BASE_IMAGE=ncs-design-base:bookworm -t ncs-design .
#
# Needs root, debootstrap and a running Docker engine. Does nothing when the tag already exists.
# The host's extra CA certificates (/usr/local/share/ca-certificates) are trusted in the image too, so pip
# behind a TLS-inspecting proxy works; DEBIAN_MIRROR overrides the mirror.
set -euo pipefail
TAG=${1:-ncs-design-base:bookworm}
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

if docker image inspect "$TAG" >/dev/null 2>&1; then
    echo "base image $TAG exists"
    exit 0
fi
ROOTFS=$(mktemp -d)
trap 'rm -rf "$ROOTFS"' EXIT
echo "== debootstrap bookworm into $ROOTFS from $MIRROR"
debootstrap --variant=minbase --include=python3,python3-venv,python3-pip,ca-certificates \
    bookworm "$ROOTFS" "$MIRROR" >"$ROOTFS.log" 2>&1 || { tail -20 "$ROOTFS.log" >&2; exit 1; }
rm -f "$ROOTFS.log"
if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
    cp /usr/local/share/ca-certificates/*.crt "$ROOTFS/usr/local/share/ca-certificates/"
    chroot "$ROOTFS" update-ca-certificates >/dev/null
fi
chroot "$ROOTFS" apt-get clean
rm -rf "$ROOTFS"/var/lib/apt/lists/* "$ROOTFS"/var/cache/apt/*.bin
echo "== docker import $TAG"
tar -C "$ROOTFS" -c . | docker import \
    --change 'ENV LANG=C.UTF-8' \
    --change 'ENV PIP_CERT=/etc/ssl/certs/ca-certificates.crt' \
    --change 'CMD ["python3"]' \
    - "$TAG" >/dev/null
echo "base image $TAG built"
