# ncs-design web service.
#
#     docker build -t ncs-design .                                   # base: python:3.11-slim (Docker Hub)
#     docker build --build-arg BASE_IMAGE=ncs-design-base:bookworm -t ncs-design .   # a local base image
#     docker run -p 8000:8000 -v ncs-data:/data ncs-design
#
# Any Debian-like base with python3 (>= 3.11, with venv) and useradd works; scripts/make_base_image.sh makes
# one from Debian's packages when Docker Hub is out of reach.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:$PATH \
    NCS_DATABASE_URL=sqlite:////data/ncs.db \
    NCS_HOST=0.0.0.0 \
    NCS_PORT=8000

WORKDIR /srv/ncs

# A virtual environment (Debian's python refuses system-wide pip installs), the service user and its data
# directory.
RUN python3 -m venv /opt/venv \
    && useradd --system --create-home --uid 10001 ncs \
    && mkdir -p /data && chown ncs:ncs /data

# Dependencies first, from pyproject.toml alone: this layer is rebuilt only when the dependencies change,
# not when the code does.
COPY pyproject.toml ./
RUN python3 -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" \
        > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt \
    && rm /tmp/requirements.txt

# Then the code (no dependency resolution any more). The migrations travel in the wheel (setup.py maps
# alembic/ to app/migrations): the service finds them without NCS_ALEMBIC_DIR.
COPY README.md alembic.ini setup.py ./
COPY alembic ./alembic
COPY solver ./solver
COPY app ./app
RUN pip install --no-deps . && python3 -c "import app.main, solver"

USER ncs
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD python -c "import os, sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:%s/readyz' % os.environ.get('NCS_PORT', '8000'), timeout=4).status == 200 else 1)"

CMD ["ncs-design", "serve"]
