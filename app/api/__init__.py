"""HTTP layer: routers, dependencies, auth, error rendering and the body-size limit."""
