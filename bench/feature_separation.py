import numpy as np, itertools, sys
from roger_sim.world import load_world
from roger_sim.simulator import Simulator
from roger_common.types import Goal, Action
from roger_perception.perception import Perception
from roger_bringup.evaluation import object_under_window
w=load_world(sys.argv[1]); s=Simulator(w, seed=1); p=Perception()
cat={o.name:o.category() for o in w.objects}
obs={}  # name -> list of (stage, features, known)
gid=1
for o in w.objects:
  tgt=(o.position[0],o.position[1],0.08)
  for act in (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT):
    r,f=s.run_goal(Goal(gid,act,tgt)); gid+=1
    rois=p.process(f)
    # ROI nearest the fixation
    best=min(rois,key=lambda x:(x.position[0]-tgt[0])**2+(x.position[1]-tgt[1])**2) if rois else None
    if best is None: continue
    t=object_under_window(f.left_labels,f.label_names,best.bbox)
    obs.setdefault(o.name,[]).append((act.name[:3],best.features.copy(),best.known.copy(),t))
def rms(a,b,ka,kb):
  k=ka&kb; return float(np.sqrt(np.mean((a[k]-b[k])**2)))
names=list(obs)
print('per object, stage: features (I1 T1 S1 D W) true')
for n in names:
  for st,fv,kn,t in obs[n]:
    print(f'  {n:7s} {st} I={fv[0]:.2f},{fv[1]:.2f},{fv[2]:.2f} T={fv[3]:.3f} S={fv[6]:.2f},{fv[7]:.2f},{fv[8]:.2f} D={fv[9]:.2f} W={fv[10]:.2f}{"" if kn[10] else "?"} true={t}')
within=[];between=[]
for a,b in itertools.combinations(names,2):
  for (sa,fa,ka,_),(sb,fb,kb,_) in itertools.product(obs[a],obs[b]):
    d=rms(fa,fb,ka,kb)
    (within if cat[a]==cat[b] else between).append(d)
for n in names:
  for (sa,fa,ka,_),(sb,fb,kb,_) in itertools.combinations(obs[n],2):
    within.append(rms(fa,fb,ka,kb))
print('within-category RMS: median %.3f  p90 %.3f max %.3f' % (np.median(within), np.percentile(within,90), max(within)))
print('between-category RMS: min %.3f  p10 %.3f median %.3f' % (min(between), np.percentile(between,10), np.median(between)))
