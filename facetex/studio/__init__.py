"""``facetex serve``: a local web studio (an ASGI app and static pages, no build step).

Four pages: Transfer (content and style, method and preset, progress, a before/after slider with
native-resolution zooms, the result and its sidecar), Persona (photos or a zip in, the build
stage by stage, expression textures, the ``.persona`` out), Puppet (a driver clip and a persona
in, the video out) and Live (the browser's camera drives a persona over a WebSocket).

Jobs run the CLI's own commands in child processes, one at a time, each in a folder of its own
under the work folder (:mod:`facetex.studio.jobs`); the studio sits above the algorithms like
``bench`` and ``batch``. Needs the ``studio`` extra: ``pip install 'facetex[studio]'``.
"""

from __future__ import annotations

from .app import create_app

__all__ = ["create_app"]
