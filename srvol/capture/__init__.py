"""From a folder of flash photos to a scene (DESIGN.md section 4): ``srvol import``.

Stages, one module each, typed values between them:

* :mod:`.photos`     -- list and read the photos (JPEG/PNG/TIFF, 8/16 bit, EXIF orientation, EXIF focal prior);
* :mod:`.sfm`        -- poses from pycolmap (SIFT, exhaustive matching, incremental mapping, largest model);
* :mod:`.external`   -- poses that already exist: a COLMAP sparse model or a transforms.json;
* :mod:`.frame`      -- similarities: the normalisation into the unit sphere, fits on camera centres;
* :mod:`.resolution` -- the working resolution: Gaussian blur of known sigma + decimation;
* :mod:`.masks`      -- automatic object masks, kept consistent across views by a visual hull;
* :mod:`.importer`   -- the whole ``srvol import`` and the scene it writes.
"""
