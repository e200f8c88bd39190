"""``xshells app``: the interactive design tool in the browser (viser).

Plain-Python core (testable without a browser): :mod:`.core` (layouts,
edits, warps, undo/redo, topology checks), :mod:`.loading` (files, uploads,
grids), :mod:`.sim` (assembly and warm-started deployed equilibria),
:mod:`.worker` (background solves), :mod:`.exports` (SVG, DXF, meshes, case
JSON, PNG), :mod:`.adapters` (optimization / actuation hooks). The viser UI
is :mod:`.ui`; :mod:`.cli` registers the subcommand.
"""
