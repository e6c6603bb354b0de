"""Regenerate the golden IR dumps of the front-end cases: `python tests/regen_cases.py`.

Writes `tests/cases/ok/NAME.ir` (the `FlatNetlist.text()` of `NAME.spr`) for every case.
Run it after an intended change of the front end or of `FlatNetlist.text()`, then read the
diff before committing it: the golden files are the specification of what each case means.
"""

from __future__ import annotations

from pathlib import Path

from springc.lang import load_file

OK_DIR = Path(__file__).resolve().parent / "cases" / "ok"


def main() -> None:
    """Rewrite every `.ir` file beside its `.spr` case."""
    for case in sorted(OK_DIR.glob("*.spr")):
        text = load_file(case).text()
        case.with_suffix(".ir").write_text(text, encoding="utf-8")
        print(f"wrote {case.with_suffix('.ir').relative_to(OK_DIR.parent.parent.parent)}")


if __name__ == "__main__":
    main()
