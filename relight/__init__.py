"""srvol.relight: point-light rendering with shadows and material edits, of the neural model and of
an exported asset, through the BRDF used in training (:func:`srvol.brdf.shade`).

Modules:

* :mod:`~srvol.relight.render`  -- ``render_fields`` (sphere-traced SDF) and ``render_asset``
  (embree-cast mesh + bilinear textures); both feed :func:`render_scene`, the one image formation.
* :mod:`~srvol.relight.edits`   -- ``--material`` specs -> :class:`MaterialEdit`.
* :mod:`~srvol.relight.sources` -- a run, an asset folder or a built-in scene's exact fields.
* :mod:`~srvol.relight.compare` -- scores and sheets against a scene's relit ground truth.
* :mod:`~srvol.relight.mitsuba_check` -- the same asset rendered by Mitsuba 3, compared.
* :mod:`~srvol.relight.synthetic` -- assets meshed and baked straight from exact fields (checks).
* :mod:`~srvol.relight.cli`     -- ``srvol relight`` / ``relight``.

Positions are in the scene frame (object in the unit sphere, +z up); lights are isotropic with
radiant intensity in W/sr; images are linear RGB (sRGB only in PNG files).
"""
