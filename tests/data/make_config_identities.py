"""Writes tests/data/config_identities.json: the identity digest (nmrl/runs/identity.py) of every
committed run config (``results/**/config.json`` of a learner), as the checkout that runs it computes.

The file kept was written at commit fd42078, where each learner's config fields, checks and traced
values are written out by hand; tests/test_options.py checks that the declarations of
nmrl/options.py give every one of these configs the same digest, so each run stays resumable.
Run: ``PYTHONPATH=. python tests/data/make_config_identities.py``
"""

import json
import pathlib

from nmrl.paper.env import MODEL_PATH
from nmrl.runs import identity
from nmrl.runs.checkpoint_files import _sha256_file

OUT = pathlib.Path(__file__).with_name("config_identities.json")


def main() -> None:
    sha = _sha256_file(MODEL_PATH)
    digests = {}
    for p in sorted(pathlib.Path("results").rglob("config.json")):
        try:
            cfg = identity.load_run_config(p.parent)
        except Exception:  # noqa: BLE001 - not a learner's run (the Brax baseline's own config)
            continue
        digests[str(p)] = identity.identity_digest(cfg, sha)
    OUT.write_text(json.dumps({"model_sha256": sha, "identity_digest": digests}, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
