"""The HTTP layer: routers, request checks, problem+json errors. The only package (with app.main) that imports FastAPI."""
