"""The pattern studio: a local web page to set a garment up from its pattern pieces (`python -m taichi_cloth studio`).

Parts, each one idea:

- folder.py:    the start folder, the only place the studio reads and writes (paths resolved, `..`, absolute paths
                and symlinks leading outside refused);
- tomlfile.py:  a garment file's content written back as TOML;
- layout.py:    the pieces laid flat for drawing: outlines, sides, corners, lengths, grain, the seams' sides;
- session.py:   the studio's state and operations, without HTTP: pieces, seams, placements, material, spacing,
                undo and redo, open, save, autosave and restore;
- views.py:     the placement picture: the mannequin and the placed pieces from the front and the side;
- drape.py:     a drape in a background process (`python -m taichi_cloth run` on a scene the studio writes) and its
                progress;
- server.py:    the HTTP routes (Starlette) and the page in static/ (plain SVG and JavaScript, no build step);
- cli.py:       the `studio` command.

docs/studio.md describes the page, the routes and the rules.
"""
