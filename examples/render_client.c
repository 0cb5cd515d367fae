/* A render-server client in plain C, written from docs/protocol.md alone.
 *
 *   cc -O2 -o render_client examples/render_client.c
 *   ./render_client HOST PORT X Y Z QW QX QY QZ TIME FRAME OUT.pgm [TOKEN]
 *
 * Sends HELLO (with TOKEN, if given), SET_POSE and GET_IMAGE (the sensor's bit depth), writes
 * the image as a binary PGM (8 or 16 bit, big-endian samples as PGM requires) and prints the
 * laser-altimeter range straight down (RAY) on stdout. Then, still at that pose, it measures
 * with the scenario's radar beam (GET_RADAR: its range and mean radial velocity), flashes the
 * LIDAR (GET_LIDAR: the range of the centre pixel) and, turning at 1 rad/s about the world x
 * axis (SET_MOTION), runs the event camera for 0.05 s (GET_EVENTS: the number of events and of ON events),
 * printing one line each. Exit status 0, or 1 with the server's error reason on stderr.
 */
#include <arpa/inet.h>
#include <netdb.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

static int fd;
static uint32_t next_id = 1;

static void put_u16(uint8_t *p, uint16_t v) { p[0] = v & 0xff; p[1] = v >> 8; }
static void put_u32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (v >> (8 * i)) & 0xff; }
static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static void put_f64(uint8_t *p, double v) {  /* IEEE 754, little-endian */
    uint64_t u; memcpy(&u, &v, 8);
    for (int i = 0; i < 8; i++) p[i] = (u >> (8 * i)) & 0xff;
}
static double get_f64(const uint8_t *p) {
    uint64_t u = 0; double v;
    for (int i = 0; i < 8; i++) u |= (uint64_t)p[i] << (8 * i);
    memcpy(&v, &u, 8);
    return v;
}

static void read_all(uint8_t *buf, size_t n) {
    size_t got = 0;
    while (got < n) {
        ssize_t k = recv(fd, buf + got, n - got, 0);
        if (k <= 0) { fprintf(stderr, "connection closed\n"); exit(1); }
        got += (size_t)k;
    }
}

/* Send one request; return the reply body (malloc'd) and its length, or exit on an error. */
static uint8_t *request(uint16_t type, const uint8_t *body, uint32_t len, uint32_t *out_len) {
    uint8_t head[16];
    memcpy(head, "CSRV", 4);
    put_u16(head + 4, 1);
    put_u16(head + 6, type);
    put_u32(head + 8, next_id);
    put_u32(head + 12, len);
    if (send(fd, head, 16, 0) != 16 || (len && send(fd, body, len, 0) != (ssize_t)len)) {
        fprintf(stderr, "send failed\n"); exit(1);
    }
    read_all(head, 16);
    if (memcmp(head, "CSRV", 4) != 0) { fprintf(stderr, "bad magic\n"); exit(1); }
    uint16_t rtype = get_u16(head + 6);
    uint32_t n = get_u32(head + 12);
    if (n > (1u << 30)) { fprintf(stderr, "reply too large\n"); exit(1); }
    uint8_t *reply = malloc(n + 1);
    read_all(reply, n);
    reply[n] = 0;
    if (rtype == 0xFFFF) {
        fprintf(stderr, "server error %u: %s\n", get_u16(reply), (char *)reply + 4);
        exit(1);
    }
    if (rtype != (type | 0x8000) || get_u32(head + 8) != next_id) {
        fprintf(stderr, "unexpected reply\n"); exit(1);
    }
    next_id++;
    *out_len = n;
    return reply;
}

int main(int argc, char **argv) {
    if (argc < 13) {
        fprintf(stderr, "usage: %s HOST PORT X Y Z QW QX QY QZ TIME FRAME OUT.pgm [TOKEN]\n",
                argv[0]);
        return 2;
    }
    struct addrinfo hints = {0}, *ai;
    hints.ai_socktype = SOCK_STREAM;
    if (getaddrinfo(argv[1], argv[2], &hints, &ai) != 0) { fprintf(stderr, "bad host\n"); return 1; }
    fd = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
    if (fd < 0 || connect(fd, ai->ai_addr, ai->ai_addrlen) != 0) {
        fprintf(stderr, "cannot connect\n"); return 1;
    }
    freeaddrinfo(ai);
    uint32_t n;
    if (argc > 13) free(request(0x0001, (uint8_t *)argv[13], (uint32_t)strlen(argv[13]), &n));

    uint8_t pose[72] = {0};
    for (int i = 0; i < 8; i++) put_f64(pose + 8 * i, atof(argv[3 + i]));  /* x..qz, time */
    put_u32(pose + 64, (uint32_t)strtoul(argv[11], NULL, 10));             /* frame index */
    free(request(0x0010, pose, 72, &n));

    uint8_t bits = 0;
    uint8_t *img = request(0x0020, &bits, 1, &n);
    uint32_t w = get_u32(img), h = get_u32(img + 4);
    uint16_t depth = get_u16(img + 8);
    size_t bpp = depth == 16 ? 2 : 1;
    if (n != 12 + (size_t)w * h * bpp) { fprintf(stderr, "bad image size\n"); return 1; }
    FILE *f = fopen(argv[12], "wb");
    if (!f) { fprintf(stderr, "cannot write %s\n", argv[12]); return 1; }
    fprintf(f, "P5\n%u %u\n%u\n", w, h, depth == 16 ? 65535u : 255u);
    for (size_t i = 0; i < (size_t)w * h; i++) {
        const uint8_t *p = img + 12 + i * bpp;
        if (bpp == 2) { fputc(p[1], f); fputc(p[0], f); } else fputc(p[0], f);
    }
    fclose(f);
    free(img);

    uint8_t ray[48] = {0};
    for (int i = 0; i < 3; i++) put_f64(ray + 8 * i, atof(argv[3 + i]));
    put_f64(ray + 40, -1.0);  /* direction (0, 0, -1) */
    uint8_t *hit = request(0x0032, ray, 48, &n);
    printf("%.6f\n", get_f64(hit));
    free(hit);

    uint8_t *radar = request(0x0026, NULL, 0, &n);  /* empty body: the scenario's beam */
    uint32_t nr = get_u32(radar), nd = get_u32(radar + 4);
    if (n != 72 + 4 * (size_t)nr * nd) { fprintf(stderr, "bad radar size\n"); return 1; }
    printf("%.6f %.6f\n", get_f64(radar + 8), get_f64(radar + 16));  /* range, velocity */
    free(radar);

    uint8_t *lidar = request(0x0027, NULL, 0, &n);  /* empty body: the scenario's LIDAR */
    uint32_t lw = get_u32(lidar), lh = get_u32(lidar + 4);
    if (n != 8 + 21 * (size_t)lw * lh) { fprintf(stderr, "bad lidar size\n"); return 1; }
    float centre;
    uint32_t bits32 = get_u32(lidar + 8 + 4 * ((size_t)(lh / 2) * lw + lw / 2));
    memcpy(&centre, &bits32, 4);
    printf("%.6f\n", (double)centre);
    free(lidar);

    uint8_t motion[72] = {0};
    put_f64(motion + 24, 1.0);    /* angular velocity (1, 0, 0) rad/s */
    free(request(0x0013, motion, 72, &n));
    uint8_t ev[12] = {0};
    put_f64(ev, 0.05);            /* duration (s); max events 0: as many as fit */
    uint8_t *events = request(0x0028, ev, 12, &n);
    uint32_t count = get_u32(events);
    if (n != 24 + 13 * (size_t)count) { fprintf(stderr, "bad events size\n"); return 1; }
    uint32_t on = 0;
    for (uint32_t i = 0; i < count; i++) on += (int8_t)events[24 + 12 * (size_t)count + i] > 0;
    printf("%u %u\n", count, on);
    free(events);
    close(fd);
    return 0;
}
