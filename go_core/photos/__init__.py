"""A folder of photos without poses made into a posed scene (docs/photos.md): ``folder`` (which photos,
read upright, camera groups), ``masks`` (every photo's object mask), ``sfm`` (pycolmap SfM on every photo),
``views`` (the normalised frame and the spread training views), ``scene`` (all of it, for the ``scene``
step and ``go-pipeline validate``)."""
