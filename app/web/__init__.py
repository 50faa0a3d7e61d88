"""The design page served at ``/``: a static page (HTML, one stylesheet, plain JavaScript, no build step) that uses
only the public /v1 API. The files ship in the wheel (setup.py's package data); app.main mounts them."""

from pathlib import Path

#: index.html, page.css, page.js and examples.json.
STATIC = Path(__file__).resolve().parent / "static"
