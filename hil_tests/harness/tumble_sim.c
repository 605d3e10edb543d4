/*
 * tumble_sim: run the tumblebot firmware ELF in simavr (ATmega328P, 16 MHz) with UART0
 * bridged to a pseudo-terminal, and report the servo pulse widths measured on D9 (PB1,
 * right servo) and D10 (PB2, left servo) from their pin edges.
 *
 *   tumble_sim FIRMWARE.elf [--unpaced]
 *
 * stdout, one event per line (times are simulated microseconds since the first start):
 *   @pty /dev/pts/N         the port to open (lines without "@" are simavr chatter)
 *   @started                the AVR runs (after "start" on stdin)
 *   @pulse T PIN WIDTH      a new pulse width in microseconds (0.1 us) on PIN 9 or 10, printed
 *                           when it differs from the last one by more than 0.75 us
 *   @reset T                the AVR was reset (command or watchdog)
 *   @time T                 simulated time, every simulated millisecond (for flow control)
 *   @rx T N                 N more bytes from the pty were handed to the AVR's UART at T (so
 *                           tests can time the firmware in simulated time, whatever the load)
 *
 * stdin commands: "start" (begin running: open the pty first, pyserial's open() discards
 * pending input), "reset" (reset the AVR now), "quit".
 *
 * The simulation is paced to the wall clock by default (real-time peers: the agent's
 * watchdogs); --unpaced runs as fast as it can (about 9.6x real time). Paced, a stall of
 * the harness itself (a starved machine) is made up at once only up to 50 ms; the rest is
 * made up at 1.5x real time. Racing through a long stall would squeeze the agent's 100 ms
 * keepalives into a few simulated ms each and trip the firmware's 250 ms watchdog, which
 * no real Uno would see; this way a keepalive gap of 100 ms real is at most 1.5 x 100 +
 * 50 = 200 ms simulated. After a long stall the emulated clock trails the wall clock for
 * a while (the twin reports the drift).
 *
 * The UART bridge is our own, run from the simulation loop (no thread): simavr 1.6's
 * uart_pty part stalls for good when its 512-byte FIFO fills (its thread then never
 * moves the rest of what it read into the FIFO until the AVR transmits something).
 */
#include <errno.h>
#include <math.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <pty.h>
#include <termios.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_timer.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>

static avr_t *avr;
static unsigned long long sim_us(void);

/* --- UART0 <-> pseudo-terminal bridge ------------------------------------------------ */
static int pty_master = -1;
static char pty_name[128];
static int uart_xon = 1;                /* the AVR's receive FIFO has room */
static avr_irq_t *uart_input;           /* raise with a byte: the AVR receives it */
static uint8_t rx_buf[512];
static ssize_t rx_len, rx_pos;
static uint8_t tx_buf[4096];
static size_t tx_len;

static void uart_output_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)param;
  if (tx_len < sizeof tx_buf) tx_buf[tx_len++] = (uint8_t)value;  /* else: the reader is gone */
}
static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)value; (void)param;
  uart_xon = 1;
}
static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)value; (void)param;
  uart_xon = 0;
}

static int bridge_open(void) {
  int slave;
  if (openpty(&pty_master, &slave, pty_name, NULL, NULL) < 0) return -1;
  struct termios tio;
  tcgetattr(pty_master, &tio);
  cfmakeraw(&tio);
  tcsetattr(pty_master, TCSANOW, &tio);
  fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
  /* keep `slave` open: the pty must not hang up between test connections */
  uint32_t flags = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  flags &= ~AVR_UART_FLAG_STDIO;
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  uart_input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_output_hook, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook, NULL);
  return 0;
}

/* Move bytes both ways; called every simulated millisecond from the simulation loop. */
static void bridge_pump(void) {
  if (tx_len > 0) {
    const ssize_t n = write(pty_master, tx_buf, tx_len);
    if (n > 0) {
      memmove(tx_buf, tx_buf + n, tx_len - (size_t)n);
      tx_len -= (size_t)n;
    }
  }
  int handed = 0;
  while (uart_xon) {
    if (rx_pos >= rx_len) {
      rx_len = read(pty_master, rx_buf, sizeof rx_buf);
      rx_pos = 0;
      if (rx_len <= 0) {
        rx_len = 0;
        break;
      }
    }
    avr_raise_irq(uart_input, rx_buf[rx_pos++]);
    ++handed;
  }
  if (handed > 0) printf("@rx %llu %d\n", sim_us(), handed);
}
static avr_cycle_count_t rise[2];
static double last_width[2] = {-1.0, -1.0};
static const int pins[2] = {9, 10};
static avr_cycle_count_t cycle_offset;  /* cycles before the last reset, so time is monotonic */

static unsigned long long sim_us(void) {
  return (unsigned long long)((cycle_offset + avr->cycle) / (avr->frequency / 1000000));
}

static void pin_changed(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  const int ch = (int)(long)param;
  if (value) {
    rise[ch] = avr->cycle;
  } else if (rise[ch] != 0 && avr->cycle > rise[ch]) {
    const double width = (double)(avr->cycle - rise[ch]) / (avr->frequency / 1e6);
    if (width > last_width[ch] + 0.75 || width < last_width[ch] - 0.75) {  /* ignore cycle jitter */
      last_width[ch] = width;
      printf("@pulse %llu %d %.1f\n", sim_us(), pins[ch], width);
      fflush(stdout);
    }
  }
}

static double wall_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Returns 1 to keep going, 0 to quit; -1 when nothing was read. */
static int read_command(int *start, int *reset) {
  static char line[64];
  static size_t len;
  char c;
  ssize_t n;
  while ((n = read(STDIN_FILENO, &c, 1)) == 1) {
    if (c != '\n') {
      if (len < sizeof line - 1) line[len++] = c;
      continue;
    }
    line[len] = 0;
    len = 0;
    if (strcmp(line, "start") == 0) *start = 1;
    else if (strcmp(line, "reset") == 0) *reset = 1;
    else if (strcmp(line, "quit") == 0) return 0;
  }
  if (n == 0) return 0;  /* stdin closed: the test is gone */
  return 1;
}

static void do_reset(void) {
  /* Some simavr versions zero avr->cycle on reset and some (Debian's 1.6) do not: add only
   * what the reset took away, so the emulated clock neither jumps nor freezes. */
  const avr_cycle_count_t before = avr->cycle;
  avr_reset(avr);
  cycle_offset += before - avr->cycle;
  rise[0] = rise[1] = 0;
  last_width[0] = last_width[1] = -1.0;
  printf("@reset %llu\n", sim_us());
  fflush(stdout);
}

int main(int argc, char **argv) {
  if (argc < 2) {
    fprintf(stderr, "usage: %s FIRMWARE.elf [--unpaced]\n", argv[0]);
    return 2;
  }
  const int paced = !(argc > 2 && strcmp(argv[2], "--unpaced") == 0);
  elf_firmware_t fw;
  memset(&fw, 0, sizeof fw);
  if (elf_read_firmware(argv[1], &fw) != 0) {
    fprintf(stderr, "tumble_sim: cannot read %s\n", argv[1]);
    return 1;
  }
  avr = avr_make_mcu_by_name("atmega328p");
  if (!avr) {
    fprintf(stderr, "tumble_sim: simavr has no atmega328p\n");
    return 1;
  }
  avr_init(avr);
  avr->frequency = 16000000;
  avr_load_firmware(avr, &fw);
  avr->frequency = 16000000;

  if (bridge_open() != 0) {
    fprintf(stderr, "tumble_sim: cannot open a pty: %s\n", strerror(errno));
    return 1;
  }
  for (int ch = 0; ch < 2; ++ch) {
    /* Timer1's compare outputs OC1A (PB1, D9) and OC1B (PB2, D10): simavr drives them
     * through these IRQs (the ioport pin IRQs do not see hardware PWM). */
    avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_TIMER_GETIRQ('1'), TIMER_IRQ_OUT_COMP + ch);
    avr_irq_register_notify(irq, pin_changed, (void *)(long)ch);
  }
  printf("@pty %s\n", pty_name);
  fflush(stdout);

  fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);
  int start = 0, reset = 0;
  while (!start) {
    struct pollfd pfd = {STDIN_FILENO, POLLIN, 0};
    poll(&pfd, 1, 100);
    if (read_command(&start, &reset) == 0) return 0;
  }
  printf("@started\n");
  fflush(stdout);

  const double t0 = wall_seconds();
  double last_wall = t0, credit = 0.0;  /* credit: the simulated seconds the pacing allows by now */
  avr_cycle_count_t next_check = 0;
  for (;;) {
    const int state = avr_run(avr);
    if (state == cpu_Done || state == cpu_Crashed) {
      do_reset();  /* a crashed AVR reboots, as the real one would via its watchdog */
    }
    const avr_cycle_count_t now = cycle_offset + avr->cycle;
    if (now < next_check) continue;
    next_check = now + 16000;  /* every simulated millisecond */
    bridge_pump();
    printf("@time %llu\n", sim_us());
    fflush(stdout);
    if (read_command(&start, &reset) == 0) break;
    if (reset) {
      reset = 0;
      do_reset();
    }
    if (paced) {
      const double emulated = (double)now / 16e6;
      for (;;) {
        const double wall = wall_seconds();
        const double dt = wall - last_wall;
        last_wall = wall;
        /* a stall is credited up to 50 ms (we check every simulated ms); behind real time,
         * run at 1.5x to catch up the rest */
        const double rate = emulated < wall - t0 - 0.001 ? 1.5 : 1.0;
        credit = fmin(credit + fmin(dt * rate, 0.05), wall - t0);
        const double ahead = emulated - credit;
        if (ahead <= 0.0005) break;
        usleep((useconds_t)(ahead / rate * 1e6));
      }
    }
  }
  fflush(stdout);
  _exit(0);
}
