#!/usr/bin/env python3
"""Ouster pcap seeds for the ouster_pcap fuzz target: python3 ouster_seed.py IN.pcap OUT.pcap [BYTES]

The target reads every input with 32-beam, 512-column metadata (fuzz/readers.cpp: a frame costs
rows x columns cells, 1.3 MB at 128 x 1024, allocated afresh per input under ASan). So the sample
captures are rewritten as such a sensor would send them: each lidar packet keeps its headers, its
first 32 pixels of every column and its footer; measurement id m of frame f becomes m mod 512 of
frame 2f + m div 512 (a 1024-column turn is two 512-column frames). The seed starts a quarter
frame before a frame ends, so it holds the end of one frame and the start of the next.
"""
import struct
import sys

PORT, BEAMS, COLUMNS, PER_PACKET = 7502, 32, 512, 16
# lidar payload bytes at 128 beams -> (profile, bytes a pixel, column header)
PROFILES = {64 + PER_PACKET * (12 + 128 * 12): ("RNG19", 12, 12), 64 + PER_PACKET * (12 + 128 * 4): ("RNG15", 4, 12)}
LEGACY = PER_PACKET * (16 + BEAMS * 12 + 4)


def rewrite(payload):
    """The payload as the 32-beam, 512-column sensor sends it, or None for other packets."""
    out = bytearray()
    if len(payload) == LEGACY:  # per column: header (measurement id at 8, frame id at 10), pixels, status
        column = len(payload) // PER_PACKET
        for c in range(PER_PACKET):
            col = bytearray(payload[c * column:(c + 1) * column])
            mid, fid = struct.unpack_from("<HH", col, 8)
            struct.pack_into("<HH", col, 8, mid % COLUMNS, (2 * fid + mid // COLUMNS) & 0xFFFF)
            out += col
        return bytes(out)
    if len(payload) not in PROFILES:
        return None
    _, pixel, header = PROFILES[len(payload)]
    column = header + 128 * pixel
    head = bytearray(payload[:32])  # packet header: frame id at 2
    (fid,) = struct.unpack_from("<H", head, 2)
    (mid0,) = struct.unpack_from("<H", payload, 32 + 8)
    struct.pack_into("<H", head, 2, (2 * fid + mid0 // COLUMNS) & 0xFFFF)
    out += head
    for c in range(PER_PACKET):
        col = bytearray(payload[32 + c * column:32 + c * column + header + BEAMS * pixel])
        (mid,) = struct.unpack_from("<H", col, 8)
        struct.pack_into("<H", col, 8, mid % COLUMNS)
        out += col
    out += payload[32 + PER_PACKET * column:]  # footer
    return bytes(out)


def main():
    src, dst = sys.argv[1], sys.argv[2]
    limit = int(sys.argv[3]) if len(sys.argv) > 3 else 65536
    data = open(src, "rb").read()
    endian = "<" if data[:4] in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1") else ">"
    records, at = [], 24
    while at + 16 <= len(data):
        sec, frac, incl, orig = struct.unpack_from(endian + "IIII", data, at)
        rec = bytearray(data[at + 16:at + 16 + incl])
        at += 16 + incl
        ip = 18 if rec[12:14] == b"\x81\x00" else 14
        if rec[ip - 2:ip] != b"\x08\x00" or rec[ip + 9] != 17:
            continue
        udp = ip + (rec[ip] & 15) * 4
        if rec[udp + 2] << 8 | rec[udp + 3] != PORT:
            continue
        payload = rewrite(bytes(rec[udp + 8:]))
        if payload is None:
            continue
        struct.pack_into(">H", rec, ip + 2, udp - ip + 8 + len(payload))  # IPv4 total length
        struct.pack_into(">H", rec, udp + 4, 8 + len(payload))  # UDP length
        rec = rec[:udp + 8] + payload
        records.append(struct.pack(endian + "IIII", sec, frac, len(rec), len(rec)) + bytes(rec))
    # Start three quarters into the first 512-column frame: its end, then the next frame.
    start = min(len(records) - 1, 3 * COLUMNS // PER_PACKET // 4) if records else 0
    out = bytearray(data[:24])
    for r in records[start:]:
        if len(out) + len(r) > limit:
            break
        out += r
    open(dst, "wb").write(bytes(out))


if __name__ == "__main__":
    main()
