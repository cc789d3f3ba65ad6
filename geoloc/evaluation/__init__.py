"""The evaluation on simulated worlds and real photos (``geoloc eval``): a tool, never imported by the runtime."""
