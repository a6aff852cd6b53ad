"""The console commands of ``drivers``: one module each, named after its script.

``holo-render`` is ``holo_render.py``; the scripts are listed in ``pyproject.toml``.
"""
