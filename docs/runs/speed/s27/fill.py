import json,glob,statistics as st,shutil,os
rows={}
for f in glob.glob('/tmp/s27/extra/*/*/*/*/auto/seed*/result/metrics.json'):
    p=f.split('/'); rows[(p[4],p[5],int(p[-3][4:]))]=json.load(open(f))
for f in glob.glob('/tmp/s27/grid/*/*/*/auto/seed*/result/metrics.json'):
    p=f.split('/'); rows[('new',p[4],int(p[-3][4:]))]=json.load(open(f))
old={'blender_lego':'docs/runs/screens_2026-11-28s23/blender_lego_drop01_seed{}.metrics.json','blender_chair':'docs/runs/screens_2026-11-28s23/blender_chair_drop01_seed{}.metrics.json',
'llff_flower':'docs/runs/speed/s22/llff_flower_auto_011784c_seed{}.metrics.json','llff_horns':'docs/runs/speed/s22/llff_horns_auto_011784c_seed{}.metrics.json'}
for s,pat in old.items():
    for x in range(3): rows[('head',s,x)]=json.load(open('/work/main/'+pat.format(x)))
os.makedirs('/work/main/docs/runs/speed/s27/cells',exist_ok=True)
for (b,s,x),d in rows.items():
    if b=='head' and x<3: continue
    json.dump(d,open(f'/work/main/docs/runs/speed/s27/cells/{s}_auto_{"7c2e26d" if b=="head" else "blocks"}_seed{x}.metrics.json','w'),indent=1)
def seeds(b,s): return sorted(x for (bb,ss,x) in rows if bb==b and ss==s)
lines=[]
for s in ('blender_lego','blender_chair','llff_flower','llff_horns'):
    f=lambda b,r: ' / '.join(f"{rows[(b,s,x)]['psnr']:.2f}" for x in r)
    ex=[x for x in seeds('new',s) if x>=3]
    lines.append(f"| {s} | {f('head',[0,1,2])} | {f('new',[0,1,2])} | {f('head',ex)} | {f('new',ex)} |")
def m(b,scenes,sd):
    per=[st.mean(rows[(b,s,x)]['psnr'] for s in scenes) for x in sd]; return st.mean(per), st.stdev(per)
def fm(scenes,sd): 
    a=m('head',scenes,sd); b=m('new',scenes,sd); return f"{a[0]:.2f} ± {a[1]:.2f} -> {b[0]:.2f} ± {b[1]:.2f} dB"
N=['blender_lego','blender_chair']; L=['llff_flower','llff_horns']
rep={'TABLE_ROWS':'\n'.join(lines),'NERF02':fm(N,[0,1,2]),'NERF35':fm(N,[3,4,5]),'NERF05':fm(N,range(6)),'LLFF02':fm(L,[0,1,2]),'LLFF34':fm(L,[3,4]),'LLFF04':fm(L,range(5))}
diffs=[rows[('new',s,x)]['psnr']-rows[('head',s,x)]['psnr'] for s in L for x in range(5)]
rep['LLFFDIFF']=', '.join(f"{d:+.2f}" for d in diffs)
k=lambda b,s,x: rows[(b,s,x)]['kernel_seconds']['raster_backward']
rep['LLFF_ROWS']='llff_horns '+' / '.join(f"{k('head','llff_horns',x):.1f}" for x in (3,4))+' -> '+' / '.join(f"{k('new','llff_horns',x):.1f}" for x in (3,4))+' s, llff_flower '+' / '.join(f"{k('head','llff_flower',x):.1f}" for x in (3,4))+' -> '+' / '.join(f"{k('new','llff_flower',x):.1f}" for x in (3,4))+' s (seeds 3 / 4)'
print(json.dumps(rep,indent=1))
json.dump(rep,open('/tmp/s27/rep.json','w'))
