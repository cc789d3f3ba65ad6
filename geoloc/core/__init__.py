"""The method's base: geodesy and the camera model, the class labels, job threads and the method's context."""
