"""Replays GateNegativeDamping on `gatewatch bench warning --trace` output, with and without
the limit-cycle reading (fire_on_limit_cycle, stop 71; docs/benchmarks.md, "Stop 71").

Usage: python negative_replay.py RATIO TRACE...   (RATIO: the at-once bar, 3.5 by default in the daemon)

For each run it re-derives every window reading from the trace line (trust, interval, regime,
ambient ratio), checks that the rule before reproduces the traced firings ("base mismatches"),
and prints the runs whose first six events change with the limit-cycle reading."""
import collections
import math
import re
import sys
num=r'(-?[\d.]+(?:e-?\d+)?)'
def opt3(s):
    m=re.match(r'Some\(\('+num+', '+num+', '+num+r'\)\)',s)
    return tuple(map(float,m.groups())) if m else None
def parse(path):
    rows=[];hdr=None
    for line in open(path):
        if line.startswith('['):
            m=re.search(r'\] (\S+) on (\S+) gate, seed (\d+)',line); hdr=(m.group(1),m.group(2),int(m.group(3))); continue
        if not line.startswith('t '): continue
        t=float(line.split()[1]); truem=re.search(r'true mean '+num,line)
        sc=re.search(r'scored (\S+) \(true mean '+num,line)
        z=re.search(r'zeta0 (Some\('+num+r'\)|None) (Some\(\('+num+', '+num+r'\)\)|None) (Some\("(\w+)"\)|None)',line)
        tup=line.split('(regime, pooled, ssi, ambient ratio, model, fit nmae, agrees, rms swing, path, growing, ssi common) ')[1].split('  scored')[0]
        # model and ssi common
        r=dict(scen=hdr[0],gate=hdr[1],seed=hdr[2],t=t,
            z=float(z.group(2)) if z.group(2) else None,
            lo=float(z.group(4)) if z.group(4) else None, hi=float(z.group(5)) if z.group(5) else None,
            src=z.group(7), cls=sc.group(1) if sc else None, truth=float(sc.group(2)) if sc else None,
            line=line)
        # ssi own: first triple after pooled; ssi common: last triple in tup
        m=re.match(r'Some\(\((Some\(\w+\)|None), (Some\(\d+\)|None), (Some\(\(.*?\)\)|None), (Some\(.*?\)|None), (Some\(\(.*?\)\)|None), (\S+), (Some\(\w+\)|None), (Some\(.*?\)|None), (\w+), (\w+), (Some\(\(.*?\)\)|None)\)\)',tup)
        if m:
            r['regime']=m.group(1); r['pooled']=m.group(2); r['ssi']=opt3(m.group(3))
            rr=re.match(r'Some\('+num+r'\)',m.group(4)); r['ratio']=float(rr.group(1)) if rr else None
            r['model']=opt3(m.group(5)); r['nmae']=m.group(6)
            sw=re.match(r'Some\('+num+r'\)',m.group(8)); r['swing']=float(sw.group(1)) if sw else None
            r['path']=m.group(9); r['growing']=m.group(10)=='true'; r['common']=opt3(m.group(11))
        rows.append(r)
    return rows
def pbelow(lo,hi,th):
    mid=(lo+hi)/2; sd=(hi-lo)/(2*1.959963984540054)
    if sd>0: return 0.5*math.erfc((mid-th)/(sd*math.sqrt(2)))
    return 1.0 if mid<th else 0.0
BAR=3.5
def reading(r,rule,R):
    lc = r.get('regime')=='Some(LimitCycle)' and (r.get('ratio') or 0)>=R
    rd=base_reading(r)
    if rule and lc and rd[0]!='neg': return ('neg',False)
    return rd
def base_reading(r):
    trusted='trusted true' in r['line']
    if not trusted or r['z'] is None or r['lo'] is None: return ('unk',)
    lo,hi=r['lo']/100,r['hi']/100
    if hi<0: return ('neg', (r.get('ratio') or 0)>=BAR and pbelow(lo,hi,0)>=0.975)
    if 1-pbelow(lo,hi,0.005)>=0.9: return ('good',)
    return ('band',)
def run(ws,rule,R):
    neg=0;good=0;firing=False;events=[]
    for r in ws:
        rd=reading(r,rule,R)
        if not firing:
            if rd[0]=='neg':
                neg+=1
                if rd[1] or neg>=2: firing=True; good=0; events.append(('fire',r['t'],r['truth'])); 
            else: neg=0
        else:
            if rd[0]=='good':
                good+=1
                if good>=2: firing=False; neg=0; events.append(('resolve',r['t'],r['truth']))
            else: good=0
    return events
def traced(ws):
    ev=[];prev=False
    for r in ws:
        f='GateNegativeDamping' in r['line'].split('firing ')[1][:80]
        if f!=prev: ev.append(('fire' if f else 'resolve',r['t'],r['truth']))
        prev=f
    return ev
if __name__=='__main__':
    R=float(sys.argv[1]); files=sys.argv[2:]
    runs=collections.defaultdict(list)
    for f in files:
        for r in parse(f): runs[(r['scen'],r['gate'],r['seed'])].append(r)
    mism=0; diffs=[]
    for k,ws in sorted(runs.items()):
        ws.sort(key=lambda r:r['t'])
        tr=traced(ws); b=run(ws,False,R); n=run(ws,True,R)
        if [e[:2] for e in tr]!=[e[:2] for e in b]: mism+=1; print('MISMATCH',k,tr[:4],b[:4])
        if [e[:2] for e in b]!=[e[:2] for e in n]: diffs.append((k,b[:6],n[:6]))
    print('runs',len(runs),'base mismatches',mism)
    for d in diffs: print(d)
