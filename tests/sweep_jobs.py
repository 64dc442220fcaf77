"""`write_job`: a finished job's folder in a sweep, as the report tests build their sweeps."""

import json
from pathlib import Path

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def write_job(sweep: Path, number: int, variant: str, psnr, seconds: float, **extra) -> Path:
    """The folder `<number>_<variant>` with an `ablation_k` result on `juggle`, `extra` over it."""
    folder = sweep / f"{number}_{variant}"
    folder.mkdir(parents=True)
    result = {
        "experiment": "ablation_k",
        "variant": variant,
        "reference_variant": "k16",
        "job": number,
        "pipeline": "relaygs",
        "scene": "juggle",
        "seed": 0,
        "psnr": psnr,
        "ssim": 0.8,
        "fg_psnr": None,
        "train_s_total": seconds,
        "train_s_computed": seconds / 2,
        "relay.k": int(variant[1:]) if variant[1:].isdigit() else None,
        **extra,
    }
    (folder / "result.json").write_text(json.dumps(result))
    return folder
