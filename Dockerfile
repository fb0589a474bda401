# syntax=docker/dockerfile:1
# Build and runtime images on Debian bookworm (OpenCV 4.6, libapriltag 3.3, GDAL 3.6,
# PROJ 9.1).
# The build stage runs the same scripts/setup.sh that the README's commands and
# CI run, so what CI exercises is what the image builds with.

FROM rust:1-bookworm AS build
WORKDIR /src
COPY scripts/setup.sh scripts/apt-install.sh scripts/
RUN bash scripts/setup.sh
COPY . .
RUN cargo build --release --locked \
    && cp target/release/gcp-tagger /usr/local/bin/gcp-tagger

FROM debian:bookworm-slim
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
# Runtime shared libraries only (no -dev packages, no compilers), pinned to
# the bookworm versions the build stage links against; tini reaps children
# and forwards SIGTERM so the service's graceful shutdown runs.
RUN apt-get update \
    && apt-get install -y --no-install-recommends \
        libopencv-core406=4.6.0+dfsg-12 libopencv-imgproc406=4.6.0+dfsg-12 \
        libopencv-calib3d406=4.6.0+dfsg-12 libopencv-contrib406=4.6.0+dfsg-12 \
        libgdal32=3.6.2+dfsg-1+b2 libproj25=9.1.1-1+b1 proj-data=9.1.1-1 \
        libapriltag3=3.3.0-1+b1 \
        tini=0.19.0-1+b3 ca-certificates=20250419~deb12u2 \
    && rm -rf /var/lib/apt/lists/*
COPY --from=build /usr/local/bin/gcp-tagger /usr/local/bin/gcp-tagger
RUN useradd --system --uid 10001 --create-home gcp \
    && mkdir /data \
    && chown gcp /data
# Read by the libraries when they load, so they belong in the environment:
# refuse absurd rasters before decoding, keep GDAL's block cache small
# (strips are read forward, full width: the cache is never re-read), never
# write .aux.xml files, and keep OpenCV from starting its own thread pool.
ENV GDAL_CACHEMAX=32 \
    GDAL_PAM_ENABLED=NO \
    OPENCV_IO_MAX_IMAGE_PIXELS=400000000 \
    OPENCV_FOR_THREADS_NUM=1 \
    GCP_TAGGER_LISTEN=0.0.0.0:8080 \
    GCP_TAGGER_DATA_DIR=/data \
    GCP_TAGGER_LOG_JSON=true \
    GCP_TAGGER_PROBE_ADDR=127.0.0.1:8080
VOLUME /data
EXPOSE 8080
USER 10001
WORKDIR /home/gcp
HEALTHCHECK --interval=15s --timeout=5s --start-period=20s --retries=3 \
    CMD ["/usr/local/bin/gcp-tagger", "probe", "--path", "/livez"]
ENTRYPOINT ["/usr/bin/tini", "--", "/usr/local/bin/gcp-tagger"]
CMD ["serve"]
