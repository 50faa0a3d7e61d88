"""ncs-design web service (FastAPI). ``from app import create_app``."""

__all__ = ["create_app", "Settings"]


def __getattr__(name):  # lazy: worker processes import app.* without FastAPI
    if name == "create_app":
        from app.main import create_app

        return create_app
    if name == "Settings":
        from app.settings import Settings

        return Settings
    raise AttributeError(name)
