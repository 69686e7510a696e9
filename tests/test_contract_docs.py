"""The plugin guide's contract table is generated from sbrdf_core/contracts.py, never edited by hand."""

from __future__ import annotations

import os
import re
from pathlib import Path

from sbrdf_core.contracts import contract_table

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "plugin-guide.md"
BLOCK = re.compile(r"(<!-- contracts:begin[^>]*-->\n)(.*?)(\n<!-- contracts:end -->)", re.S)


def test_plugin_guide_table_matches_the_contracts():
    text = GUIDE.read_text()
    m = BLOCK.search(text)
    assert m, "docs/plugin-guide.md lost its contracts block"
    if os.environ.get("SBRDF_UPDATE_DOCS"):
        GUIDE.write_text(text[:m.start(2)] + contract_table() + text[m.end(2):])
        return
    assert m.group(2) == contract_table(), "run SBRDF_UPDATE_DOCS=1 pytest tests/test_contract_docs.py"
