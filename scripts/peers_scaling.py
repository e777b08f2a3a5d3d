#!/usr/bin/env python3
"""Data-parallel scaling on paper, from measured figures (docs/results.md, "Training on
several peers"): steps a second of one run split over N peers, for a step of T ms on one
device, with the all-reduce over several interconnects.

Model, for N >= 2 (N = 1 is the step itself):
    T_N = T_rep + (T - T_rep) / N + T_pack + T_stage + 2 (N - 1) / N * S / BW
          + 2 (N - 1) * alpha
  T_rep    what every peer repeats whatever its share (Adam, the grid updates, sampling
           the whole batch), measured on the CPU as a share of the step
  S        bytes all-reduced a step (measured)
  T_pack   the gradients packed into one buffer and unpacked (measured on the CPU)
  T_stage  a GPU's gradient copied to the host and back over PCIe (2 S / 25 GB/s), as
           talkin's exchange does (MPI on host buffers); 0 on the CPU and for NVLink,
           which assumes a device-direct all-reduce (NCCL or CUDA-aware MPI)
  BW       the ring all-reduce's bus bandwidth; alpha its per-hop latency

Usage: scripts/peers_scaling.py --mb 24.39 --loopback-ms 16.0 --pack-ms 12.5 \
           --step cpu=183:0.064 --step h200=24.5:0.61   (label=ms:repeated share)
"""

import argparse

LINKS = [
    # name, GB/s, alpha (s), staged through the host for a GPU
    ("one node, PCIe (MPI through host memory)", None, 5e-6, True),
    ("one node, NVLink (device-direct)", 300.0, 10e-6, False),
    ("nodes, 10 Gb/s Ethernet", 1.1, 30e-6, True),
    ("nodes, 100 Gb/s", 11.0, 10e-6, True),
]
PCIE_GBS = 25.0


PACK_S = 0.0


def step_s(t, rep, n, mb, gbs, alpha, staged, gpu):
    if n == 1:
        return t
    s = mb * 1e6
    stage = 2 * s / (PCIE_GBS * 1e9) if (staged and gpu) else 0.0
    ring = 2 * (n - 1) / n * s / (gbs * 1e9) + 2 * (n - 1) * alpha
    return rep * t + (1 - rep) * t / n + PACK_S + stage + ring


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mb", type=float, required=True, help="MB all-reduced a step")
    ap.add_argument("--loopback-ms", type=float, required=True,
                    help="the all-reduce's time on loopback (2 peers, shared memory)")
    ap.add_argument("--step", action="append", required=True,
                    help="label=ms:repeated, a step's time on one device and the share of "
                         "it every peer repeats (labels with 'cpu' are not staged through "
                         "PCIe)")
    ap.add_argument("--pack-ms", type=float, default=0.0,
                    help="packing and unpacking a step's buffer (measured)")
    ap.add_argument("--zero-blocks", type=float, default=0.0,
                    help="share of the gradient's blocks zero on every peer (measured)")
    ap.add_argument("--peers", default="1,2,4,8")
    a = ap.parse_args()
    global PACK_S
    PACK_S = a.pack_ms / 1e3
    peers = [int(x) for x in a.peers.split(",")]
    # Two peers on loopback: the ring moves S each way, so its bus bandwidth is S / t.
    loop_gbs = a.mb / 1e3 / (a.loopback_ms / 1e3)
    print(f"S = {a.mb:.2f} MB a step; loopback bus bandwidth {loop_gbs:.1f} GB/s\n")
    print("| step on one device | interconnect | " +
          " | ".join(f"{n} peer{'s' if n > 1 else ''}" for n in peers) + " | best |")
    print("|---|---|" + "---|" * (len(peers) + 1))
    steps = []
    for spec in a.step:
        label, rest = spec.split("=")
        ms, rep = rest.split(":")
        steps.append((label, float(ms), float(rep)))
    for label, ms, rep in steps:
        t = ms / 1e3
        gpu = "cpu" not in label
        for name, gbs, alpha, staged in LINKS:
            gbs = loop_gbs if gbs is None else gbs
            rates = [1 / step_s(t, rep, n, a.mb, gbs, alpha, staged, gpu) for n in peers]
            best = peers[max(range(len(peers)), key=lambda i: rates[i])]
            cells = " | ".join(f"{r:.1f} ({r * t:.2f}x)" for r in rates)
            print(f"| {label} ({ms:g} ms, {rep:.0%} repeated) | {name} | {cells} | {best} |")
    print("\nLevers, 8 peers over 10 Gb/s (steps a second):")
    for label, ms, rep in steps:
        t = ms / 1e3
        gpu = "cpu" not in label
        for lever, mb in [("as built", a.mb), ("half-precision gradients", a.mb / 2),
                          ("touched blocks only", a.mb * (1 - a.zero_blocks))]:
            r = 1 / step_s(t, rep, 8, mb, 1.1, 30e-6, True, gpu)
            print(f"- {label}, {lever} ({mb:.1f} MB): {r:.1f}")


if __name__ == "__main__":
    main()
