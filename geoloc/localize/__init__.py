"""The map side of the method: a photo's evidence against the map, to poses, identities and answers.

Entries: :func:`geoloc.localize.reference.label_reference_photo` (label a geo-tagged reference),
:func:`geoloc.localize.query.geolocate` (answer a query). Underneath: the likelihood
(:class:`geoloc.localize.map_likelihood.MapLikelihood`), the posterior and grid localisation, refinement,
identities and their transfer, map anchors and PnP, retrieval with the one SBoW index.
"""
