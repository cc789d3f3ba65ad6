"""The geolocation method as plain functions on numpy arrays (no HTTP, no SQL).

One module per pipeline stage; see DESIGN.md in the shared folder and README.md.
"""

__version__ = "0.1.0"
