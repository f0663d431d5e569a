import re, sys, glob, collections
d = sys.argv[1]
f = sorted(glob.glob(d + "/*jit__lambda.cpu_after_optimizations-live-range.txt"))[-1].replace("-live-range.txt", "")
sizes = {}
for line in open(f + "-buffer-assignment.txt"):
    m = re.match(r"\s*value: <\d+ (\S+) @\d+> \(size=(\d+),offset=\d+\): (.*)", line)
    if m: sizes[m.group(1)] = (int(m.group(2)), m.group(3))
txt = open(f + "-live-range.txt").read()
peak = txt[txt.index("Live ranges at"):]
print(peak.splitlines()[0])
names = [l.strip().split(':')[0].split('{')[0] for l in peak.splitlines()[1:] if l.strip()]
c = collections.Counter()
tot = 0
for n in names:
    if n in sizes:
        s, sh = sizes[n]; tot += s; c[re.sub(r"\{.*", "", sh)] += s
print("live at peak MB %.1f" % (tot / 2**20))
for sh, s in c.most_common(15): print("  %7.1f %s" % (s / 2**20, sh))
if len(sys.argv) > 2:
    for n in names:
        if n in sizes and sys.argv[2] in sizes[n][1]: print("   ", n, sizes[n][1])
