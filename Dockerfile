# MXS planner API. Build: docker build -t mxs-planner .   Run: docker compose up -d
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MPLBACKEND=Agg \
    MXS_JOB_DB=/data/jobs.sqlite3

WORKDIR /app
COPY pyproject.toml README.md ./
COPY models ./models
COPY solvers ./solvers
COPY planner ./planner
COPY service ./service
# the 'distributed' extra lets the same image run the Dask scheduler and workers (compose.yaml)
ARG EXTRAS=distributed
RUN pip install ".[${EXTRAS}]" \
    && (cd / && python -c "from planner.kernels import compile_kernels; compile_kernels()") \
    && useradd --create-home --uid 10001 mxs \
    && mkdir -p /data \
    && chown mxs:mxs /data

USER mxs
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD python -c "import urllib.request, sys; r = urllib.request.urlopen('http://127.0.0.1:8000/v1/health/live', timeout=4); sys.exit(0 if r.status == 200 else 1)"

CMD ["mxs-planner", "serve", "--host", "0.0.0.0", "--port", "8000"]
