# syntax=docker/dockerfile:1
# Build and runtime images on Debian bookworm (OpenCV 4.6, GDAL 3.6, PROJ 9.1).
# The build stage runs the same scripts/setup.sh that the README's commands and
# CI run, so what CI exercises is what the image builds with.

FROM rust:1-bookworm AS build
WORKDIR /src
COPY scripts/setup.sh scripts/setup.sh
RUN bash scripts/setup.sh
COPY . .
RUN cargo build --release --locked && cp target/release/gcp-tagger /usr/local/bin/gcp-tagger

FROM debian:bookworm-slim
# Runtime shared libraries only (no -dev packages, no compilers).
RUN apt-get update \
    && apt-get install -y --no-install-recommends \
        libopencv-core406 libopencv-imgproc406 libopencv-calib3d406 libopencv-contrib406 \
        libgdal32 libproj25 proj-data tini ca-certificates \
    && rm -rf /var/lib/apt/lists/*
COPY --from=build /usr/local/bin/gcp-tagger /usr/local/bin/gcp-tagger
RUN useradd --system --uid 10001 --create-home gcp
# Refuse absurd rasters before decoding; keep GDAL's block cache small
# (strips are read forward, full width: the cache is never re-read).
ENV GDAL_CACHEMAX=32 \
    OPENCV_IO_MAX_IMAGE_PIXELS=400000000 \
    GCP_TAGGER_LOG=info
RUN mkdir /data && chown gcp /data
VOLUME /data
EXPOSE 8080
USER gcp
WORKDIR /home/gcp
ENTRYPOINT ["/usr/bin/tini", "--", "/usr/local/bin/gcp-tagger"]
CMD ["serve", "--listen", "0.0.0.0:8080", "--data-dir", "/data", "--log-json"]
