"""Build lwm_models/text/stress_set.json: the project's free-form stress set of descriptions.

Every phrase was written for this project (the banks are in lwm_models/text/free_form.py).
The set covers all 108 (identity, movement, role) triples in each of seven styles, and it has
three parts that share no template and as few phrases as possible:

- "tune": one description per (style, triple); the keyword parser may be tuned on it, a model may
  be trained on it;
- "heldout": two descriptions per (style, triple), written with other templates, other synonyms,
  other movement and role phrases and other typo kinds; nothing is ever tuned or trained on it;
- "dev": one description per (style, triple) from a third bank; it may choose between ways of
  reading, but nothing is trained on it. It is drawn after the other two, so adding it left them
  unchanged. (Since 2026-11-28 the parser's rules know its phrasings.)
- "written": one description per (style, triple), each written by hand by a writer who saw none of
  the banks, the other parts or the parser's rules (lwm_models/text/stress_written.json, copied
  in as it is); a second dev part, for choices that need wording nothing was tuned on.

So held-out accuracy measures reading of wording the tuning never saw, not of unseen rows of seen
templates. The output is deterministic (seeded), so re-running this script changes nothing unless
the phrase banks change.

    .venv/bin/python scripts/make_stress_set.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.messenger.constants import ALL_TRIPLES  # noqa: E402
from lwm_models.text.free_form import STYLES, describe  # noqa: E402
from lwm_models.text.stress import PARTS  # noqa: E402

OUT = ROOT / "lwm_models" / "text" / "stress_set.json"
WRITTEN = ROOT / "lwm_models" / "text" / "stress_written.json"


def build() -> list[dict]:
    rng = np.random.default_rng(30)
    entries = []
    for part, per_triple in (("tune", 1), ("heldout", 2), ("dev", 1)):
        for style in STYLES:
            for triple in ALL_TRIPLES:
                made: set[str] = set()
                for _ in range(per_triple):
                    for _attempt in range(20):
                        text = describe(part, style, triple, rng)
                        if text not in made:
                            break
                    made.add(text)
                    ident, movement, role = triple
                    entries.append(
                        {
                            "text": text,
                            "identity": ident,
                            "role": role,
                            "movement": movement,
                            "style": style,
                            "split": part,
                        }
                    )
    fields = ("text", "identity", "role", "movement", "style")
    written = json.loads(WRITTEN.read_text(encoding="utf-8"))["entries"]
    return entries + [{**{k: e[k] for k in fields}, "split": "written"} for e in written]


def main() -> int:
    entries = build()
    for part in ("tune", "dev", "written"):
        seen = {e["text"] for e in entries if e["split"] == part}
        overlap = [e["text"] for e in entries if e["split"] == "heldout" and e["text"] in seen]
        if overlap:
            raise SystemExit(f"{len(overlap)} held-out descriptions also in the {part} part, e.g. {overlap[0]!r}")
    doc = {
        "_about": [
            "The project's free-form stress set of Messenger descriptions (issue 30), written for the project.",
            "Built by scripts/make_stress_set.py; each entry's split is 'tune' (may be tuned or trained on),",
            "'dev' (may choose between ways of reading, never trained on), 'heldout' (never tuned or trained on)",
            "or 'written' (a second dev part, written by hand). The parts use different templates and phrase banks.",
        ],
        "styles": list(STYLES),
        "entries": entries,
    }
    OUT.write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    counts = {part: sum(e["split"] == part for e in entries) for part in PARTS}
    print(f"{OUT.relative_to(ROOT)}: {len(entries)} descriptions, {counts}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
