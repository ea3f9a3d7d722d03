"""Regenerate the bundled example ``cstiffjax/examples/concealed/`` (robot.toml +
recordings.csv) that ``cstiffjax diagnose`` runs on with no arguments. The answer key is
written next to this script (``benchmarks/concealed_key.json``), not next to the data.

    python benchmarks/make_concealed_example.py
"""

import json
from pathlib import Path

from fitting.synth.generate import default_cases, write_case

HERE = Path(__file__).parent
CASE = "proto_exit_friction"

if __name__ == "__main__":
    case = next(c for c in default_cases() if c.name == CASE)
    out = HERE.parent / "cstiffjax" / "examples" / "concealed"
    key = write_case(case, out, n=90, seed=2026)
    text = (out / "robot.toml").read_text().replace(f'name = "{CASE}"', 'name = "concealed"')
    (out / "robot.toml").write_text(text)
    (HERE / "concealed_key.json").write_text(json.dumps(key, indent=1) + "\n")
    print(f"wrote {out} (key: {HERE / 'concealed_key.json'})")
