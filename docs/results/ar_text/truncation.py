"""Where the joined prefix's 128-token window cuts, per caption level (the 1,200-clip prefix)."""
import json, numpy as np
from handx_jax.text.tokenizer import Tokenizer, sentinel
from handx_jax.text.cache import joined_texts
from handx_jax import standard
tok = Tokenizer.load(standard.encoder_dir())
texts = [json.loads(l) for l in open("/tmp/h30/D/texts.jsonl")]
J = joined_texts(texts)
s1, s2, s3 = (tok.sentinel_id(i) for i in (1, 2, 3))
out = {}
for lv in range(5):
    n = []; right_cut = inter_cut = inter_lost = 0; cut = 0
    for t in J:
        ids = tok.encode_one(t["joined"][lv]); n.append(len(ids))
        if len(ids) > 128:
            cut += 1
            p1, p2 = ids.index(s1), ids.index(s2)
            if p1 >= 128: right_cut += 1
            if p2 >= 128: inter_lost += 1
    n = np.array(n)
    out[lv] = dict(mean_tokens=round(float(n.mean()), 1), max=int(n.max()), truncated=cut, right_text_lost=right_cut,
                   interaction_text_lost=inter_lost, clips=len(J))
print(json.dumps(out, indent=1))
