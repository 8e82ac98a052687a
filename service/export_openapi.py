"""Write the app's OpenAPI document: ``python -m service.export_openapi [PATH]``.

Default path: ``openapi/openapi.json`` at the repository root. ``tests/test_openapi.py``
fails when the committed document differs from what the app serves.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

DEFAULT_PATH = Path(__file__).resolve().parent.parent / "openapi" / "openapi.json"


def openapi_document() -> dict[str, Any]:
    from service.app import create_app
    from service.settings import Settings

    # the committed contract does not depend on this machine's token (the token is optional
    # in it; a server with a token serves it as required)
    return create_app(Settings(_env_file=None, api_token=None)).openapi()


def render(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, sort_keys=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    path = Path(argv[0]) if argv else DEFAULT_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render(openapi_document()))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
