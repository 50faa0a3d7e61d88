# ncs-design web service: docker build -t ncs-design . && docker run -p 8000:8000 -v ncs-data:/data ncs-design
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    NCS_DATABASE_URL=sqlite:////data/ncs.db \
    NCS_HOST=0.0.0.0 \
    NCS_PORT=8000 \
    NCS_ALEMBIC_DIR=/srv/ncs/alembic

WORKDIR /srv/ncs

# Dependencies first (cached layer), then the code.
COPY pyproject.toml README.md ./
COPY solver ./solver
COPY app ./app
COPY alembic ./alembic
COPY alembic.ini ./
RUN pip install . \
    && useradd --system --create-home --uid 10001 ncs \
    && mkdir -p /data && chown ncs:ncs /data

USER ncs
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD python -c "import os, sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:%s/readyz' % os.environ.get('NCS_PORT', '8000'), timeout=4).status == 200 else 1)"

CMD ["ncs-design", "serve"]
