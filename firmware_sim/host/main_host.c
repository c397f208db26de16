/* uwb-fw: the firmware built for a Linux host. Serves the protocol on a tty (a pty slave created by
 * the harness, or a real UART) or on stdin/stdout, until the link closes or SIGTERM/SIGINT. */
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "firmware.h"

typedef struct {
    int fd;
    uint8_t buf[65536];
    size_t len;
    int failed;
} out_buf_t;

static volatile sig_atomic_t stop_requested;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

static void flush_out(out_buf_t *o)
{
    size_t off = 0;
    while (off < o->len && !o->failed) {
        ssize_t w = write(o->fd, o->buf + off, o->len - off);
        if (w > 0) {
            off += (size_t)w;
        } else if (w < 0 && (errno == EINTR || errno == EAGAIN)) {
            continue;
        } else {
            o->failed = 1; /* link gone: stop serving */
        }
    }
    o->len = 0;
}

/* Replies are buffered and flushed once per received chunk: one write() per burst, not per frame. */
static void write_cb(void *ctx, const uint8_t *data, size_t n)
{
    out_buf_t *o = (out_buf_t *)ctx;
    if (o->len + n > sizeof o->buf) {
        flush_out(o);
    }
    memcpy(o->buf + o->len, data, n);
    o->len += n;
}

static int set_raw(int fd, speed_t baud)
{
    struct termios t;
    if (tcgetattr(fd, &t) != 0) {
        return -1;
    }
    /* Raw 8N1, no echo, no translation, blocking reads of at least one byte. */
    t.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON | IXOFF);
    t.c_oflag &= ~(tcflag_t)OPOST;
    t.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | CSTOPB);
    t.c_cflag |= (tcflag_t)(CS8 | CREAD | CLOCAL);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    if (baud != 0) {
        cfsetispeed(&t, baud);
        cfsetospeed(&t, baud);
    }
    return tcsetattr(fd, TCSANOW, &t);
}

static speed_t baud_const(long baud)
{
    switch (baud) {
    case 9600: return B9600;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
#ifdef B921600
    case 921600: return B921600;
#endif
#ifdef B1000000
    case 1000000: return B1000000;
#endif
    default: return 0;
    }
}

static void usage(const char *argv0)
{
    fprintf(stderr,
            "usage: %s --tty PATH [--baud N] | --stdio\n"
            "Serves the uwb-hil protocol (see protocol/messages.toml) on a tty or stdin/stdout.\n",
            argv0);
}

typedef struct {
    const char *tty; /* --tty PATH, or NULL with --stdio */
    long baud;       /* --baud N, 0: leave the tty's speed */
    int use_stdio;
} host_args_t;

/* 0 when the command line is one of the two usages, else 2 (usage printed). */
static int parse_args(int argc, char **argv, host_args_t *a)
{
    int i;
    memset(a, 0, sizeof *a);
    for (i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--tty") == 0 && i + 1 < argc) {
            a->tty = argv[++i];
        } else if (strcmp(argv[i], "--baud") == 0 && i + 1 < argc) {
            a->baud = strtol(argv[++i], NULL, 10);
        } else if (strcmp(argv[i], "--stdio") == 0) {
            a->use_stdio = 1;
        } else {
            usage(argv[0]);
            return 2;
        }
    }
    if ((a->tty == NULL) == (a->use_stdio == 0)) {
        usage(argv[0]);
        return 2;
    }
    return 0;
}

/* Feed what arrives on in_fd to the firmware, flushing its replies after each chunk, until a stop signal,
 * end of input or a failed write. */
static void serve(firmware_t *fw, out_buf_t *out, int in_fd)
{
    uint8_t buf[4096];
    while (!stop_requested && !out->failed) {
        ssize_t n = read(in_fd, buf, sizeof buf);
        if (n > 0) {
            firmware_feed(fw, buf, (size_t)n);
            flush_out(out);
        } else if (n < 0 && errno == EINTR) {
            continue;
        } else {
            break; /* 0 = EOF, EIO = the other end of the pty closed */
        }
    }
}

int main(int argc, char **argv)
{
    static firmware_t fw; /* static: the estimator state is large for a stack */
    static out_buf_t out;
    host_args_t args;
    int in_fd;
    struct sigaction sa;

    if (parse_args(argc, argv, &args) != 0) {
        return 2;
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    if (args.use_stdio) {
        in_fd = STDIN_FILENO;
        out.fd = STDOUT_FILENO;
    } else {
        in_fd = open(args.tty, O_RDWR | O_NOCTTY);
        if (in_fd < 0) {
            fprintf(stderr, "uwb-fw: cannot open %s: %s\n", args.tty, strerror(errno));
            return 1;
        }
        if (set_raw(in_fd, baud_const(args.baud)) != 0) {
            fprintf(stderr, "uwb-fw: cannot set raw mode on %s: %s\n", args.tty, strerror(errno));
            return 1;
        }
        out.fd = in_fd;
    }
    firmware_init(&fw, write_cb, &out, "host");
    fprintf(stderr, "uwb-fw %d.%d.%d serving %s\n", FW_VERSION_MAJOR, FW_VERSION_MINOR, FW_VERSION_PATCH,
            args.use_stdio ? "stdio" : args.tty);
    serve(&fw, &out, in_fd);
    fprintf(stderr, "uwb-fw: stopping (frames ok %lu, crc errors %lu, framing errors %lu)\n",
            (unsigned long)fw.stats.frames_ok, (unsigned long)fw.stats.crc_errors,
            (unsigned long)fw.stats.framing_errors);
    return 0;
}
