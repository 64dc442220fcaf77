"""docs/python.md runs: its code blocks, in order, against a stored deform model and its scene,
with the page's example store, key and scene folder swapped for the test's."""

import contextlib
import io
import re
from pathlib import Path

PAGE = Path(__file__).resolve().parents[1] / "docs" / "python.md"
EXAMPLE_ROOT = '"outputs/artifacts"'
EXAMPLE_KEY = '"2ec914192ee2"'
EXAMPLE_SCENE = '"outputs/scenes/juggle-fc11a31e10c2"'


def _page_code() -> str:
    """The page's ```python blocks joined into one program."""
    blocks = re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) >= 4, f"expected the page's code blocks in {PAGE}"
    return "\n".join(blocks)


def test_the_python_page_runs_against_a_stored_model(stored_deform, stage_scene_path):
    store, key = stored_deform
    code = _page_code()
    for example in (EXAMPLE_ROOT, EXAMPLE_KEY, EXAMPLE_SCENE):
        assert code.count(example) == 1, f"{PAGE} no longer uses {example}"
    code = (
        code.replace(EXAMPLE_ROOT, repr(str(store.root)))
        .replace(EXAMPLE_KEY, repr(key[:12]))
        .replace(EXAMPLE_SCENE, repr(str(stage_scene_path)))
    )
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, str(PAGE), "exec"), {"__name__": "docs_python"})
    lines = printed.getvalue().splitlines()
    assert lines[0].startswith("deform 8 ")  # stage, frames of the stage scene
    assert re.fullmatch(r"frame 0, camera 0: PSNR \d+\.\d\d dB, SSIM 0\.\d{4}", lines[1])
    assert re.fullmatch(r"PSNR \d+\.\d\d dB over 8 images", lines[2])  # 4 cameras × frames 0, 4
    assert lines[4] == "8 (27, 48, 3) (14, 24, 3)"  # orbit views; a half-size camera
    assert [line.split()[0] for line in lines[5:]] == ["bg", "fg"]
