import torch, sys
a = torch.load(sys.argv[1]); b = torch.load(sys.argv[2])
for k in a:
    diffs = [(x - y).abs().max().item() for x, y in zip(a[k], b[k])]
    same = all(torch.equal(x, y) for x, y in zip(a[k], b[k]))
    print(k, 'bit-identical' if same else 'DIFF', ['%.2e' % d for d in diffs])
