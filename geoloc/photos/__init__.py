"""Photos in: the one loader (:mod:`geoloc.photos.photo`) and the EXIF reader and writer (:mod:`geoloc.photos.exif`)."""
