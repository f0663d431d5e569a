"""ar.train on the real data, in process; per logged step: RSS and glibc heap stats."""
import ctypes, sys, tempfile, time
sys.path.insert(0, "/work/main")
import handx_jax
from handx_jax.families import ar
from handx_jax import train as T
class MI2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL("libc.so.6"); libc.mallinfo2.restype = MI2
def rss(): return int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
depth = int(sys.argv[1]); steps = int(sys.argv[2]); extra = sys.argv[3:]
if depth: T.cpu_steps_in_flight = lambda *a: depth
t0 = time.perf_counter()
def on_log(row):
    mi = libc.mallinfo2()
    print(f"step {row['step']:3d} {'eval' if 'eval/nll' in row else '    '} t {time.perf_counter()-t0:6.1f}s rss {rss():6.0f} MB  heap {mi.arena/2**20:6.0f} used {mi.uordblks/2**20:6.0f} free {mi.fordblks/2**20:6.0f} top {mi.keepcost/2**20:6.0f} mmap {mi.hblkhd/2**20:5.0f}", flush=True)
cfg = ar.make_config("small", [f"train.steps={steps}", "train.log_every=1", *extra], data="/tmp/h30/D",
                     encoder="/work/main/handx_jax/assets/standard/encoder", tokenizer="/tmp/h30/tok_mem")
with tempfile.TemporaryDirectory() as tmp:
    ar.train(tmp + "/r", cfg, on_log=on_log)
print("peak rss MB", __import__("resource").getrusage(0).ru_maxrss / 1024)
