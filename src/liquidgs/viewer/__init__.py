"""The browser viewer (`liquidgs view`): runs and exported PLYs, rendered by `rasterize` on the server."""
