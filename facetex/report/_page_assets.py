"""The report page's style sheet and script (sorting, the viewer, folding)."""

from __future__ import annotations

__all__ = [
]


_CSS = """
body{font:14px/1.45 system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0 auto;max-width:1500px;padding:0 18px 60px;color:#222}
h1{font-size:22px;margin:14px 0 4px}h2{border-bottom:2px solid #ddd;padding-bottom:3px;margin-top:30px;font-size:19px}
h3{margin-top:22px;font-size:16px}
#toc{font-size:13px;background:#f7f7f9;border:1px solid #e3e3e8;padding:6px 12px;margin:8px 0 4px;columns:2 340px}
#toc ol{margin:2px 0;padding-left:18px}#toc li{break-inside:avoid}
table{border-collapse:collapse;margin:6px 0 10px;font-size:13px}th,td{border:1px solid #ddd;padding:3px 7px;text-align:right;vertical-align:top}
thead th{background:#f0f0f0;text-align:center}th.m,th.metric,td.lab,td.rank,td.files{text-align:left}
table.t1 td,table.paired td{white-space:nowrap}table.t1 td.paper,table.t1 th.paper{background:#f7f3ea;color:#555}
td.wins,span.wins{color:#555;font-size:12px}span.ci{color:#555;font-size:12px}td.decided{font-weight:600}
table.kv th{text-align:left;background:#f6f6f6}table.kv td{text-align:left;font-family:monospace}
tr.nondefault th,tr.nondefault td{background:#fff4d6}
.note{color:#666;font-size:12px;max-width:1100px}
.scroll{overflow-x:auto}
table.items tbody tr{cursor:pointer}table.items tbody tr:hover{background:#eef4ff}
table.items tr.highlight{background:#ffe9e6}
table.sortable th[data-sort]{cursor:pointer;user-select:none}
table.sortable th[aria-sort=ascending]::after{content:" ▲"}table.sortable th[aria-sort=descending]::after{content:" ▼"}
td.files summary{cursor:pointer;color:#2a5db0}td.files details[open]{white-space:nowrap}
td.thumbs{white-space:nowrap;text-align:left}td.thumbs img{height:64px;width:auto;margin-right:2px;border:1px solid #ccc}
img.figure{max-width:100%}img.sheet{max-width:100%}
#viewer{display:none;position:fixed;inset:0;background:#161616;z-index:10;overflow:auto;color:#eee}
#viewer.open{display:block}
#viewer .bar{position:sticky;top:0;background:#0d0d0d;padding:6px 10px;display:flex;gap:8px;align-items:center;z-index:1}
#viewer button{background:#333;color:#eee;border:1px solid #555;padding:3px 10px;cursor:pointer;border-radius:3px}
#viewer section{padding:4px 16px 30px}#viewer h3,#viewer h4{color:#eee}
#viewer .vthumbs img{height:auto;width:auto;max-width:none;margin:0 6px 6px 0;border:1px solid #444}
#viewer .vthumbs figure{display:inline-block;margin:0 8px 8px 0;text-align:center;font-size:12px}
.zrow{display:flex;flex-wrap:wrap;gap:10px;align-items:flex-start;margin:0 0 14px;border-top:1px solid #333;padding-top:6px}
.zlab{width:90px;font-weight:600}.zrow figure{margin:0;font-size:12px;color:#ccc}
img.crop{image-rendering:pixelated;max-width:none}
pre{background:#f7f7f7;padding:8px;overflow:auto;max-height:420px;font-size:12px}
code{background:#f3f3f3;padding:0 3px}
"""

_JS = r"""
(function(){
  function num(td){var v=td.getAttribute('data-v');return v===null||v===''?NaN:parseFloat(v);}
  // sortable tables: numbers by data-v (missing values last), text by its content
  Array.prototype.forEach.call(document.querySelectorAll('table.sortable'),function(table){
    var ths=table.tHead.rows[0].cells;
    Array.prototype.forEach.call(ths,function(th,col){
      if(!th.dataset.sort)return;
      th.addEventListener('click',function(){
        var asc=th.getAttribute('aria-sort')!=='ascending';
        Array.prototype.forEach.call(ths,function(o){o.removeAttribute('aria-sort');});
        th.setAttribute('aria-sort',asc?'ascending':'descending');
        var body=table.tBodies[0],rows=Array.prototype.slice.call(body.rows);
        rows.sort(function(a,b){
          var x,y;
          if(th.dataset.sort==='num'){x=num(a.cells[col]);y=num(b.cells[col]);
            if(isNaN(x)&&isNaN(y))return 0;if(isNaN(x))return 1;if(isNaN(y))return -1;return asc?x-y:y-x;}
          x=a.cells[col].textContent;y=b.cells[col].textContent;return asc?x.localeCompare(y):y.localeCompare(x);
        });
        rows.forEach(function(r){body.appendChild(r);});
      });
    });
  });
  // the viewer: a row's images (its thumbnails, at their own size) and its native-resolution zooms
  var viewer=document.getElementById('viewer'),caption=document.getElementById('viewer-caption'),current=null;
  function fill(sec){
    var box=sec.querySelector('.vthumbs');if(box.childElementCount)return;
    var row=document.querySelector('tr[data-open="'+sec.id+'"]');if(!row)return;
    Array.prototype.forEach.call(row.querySelectorAll('img.thumb'),function(t){
      var f=document.createElement('figure'),i=t.cloneNode();i.className='vthumb';
      var c=document.createElement('figcaption');c.textContent=t.dataset.label;f.appendChild(i);f.appendChild(c);box.appendChild(f);});
  }
  function open(id){
    var sec=document.getElementById(id);if(!sec)return;
    if(current)current.hidden=true;
    fill(sec);sec.hidden=false;current=sec;viewer.classList.add('open');viewer.scrollTop=0;
    caption.textContent=sec.dataset.label;
  }
  function step(d){
    if(!current)return;
    var table=document.querySelector('table.items[data-group="'+current.dataset.group+'"]');
    var ids=Array.prototype.map.call(table.tBodies[0].rows,function(r){return r.dataset.open;}).filter(function(x){return document.getElementById(x);});
    var k=ids.indexOf(current.id);open(ids[(k+d+ids.length)%ids.length]);
  }
  function close(){if(current)current.hidden=true;current=null;viewer.classList.remove('open');}
  document.addEventListener('click',function(e){
    if(e.target.closest('a,summary,details'))return;  // a link or the files list: not the viewer
    var tr=e.target.closest('tr[data-open]');if(tr)open(tr.dataset.open);
  });
  document.getElementById('viewer-close').addEventListener('click',close);
  document.getElementById('viewer-prev').addEventListener('click',function(){step(-1);});
  document.getElementById('viewer-next').addEventListener('click',function(){step(1);});
  document.addEventListener('keydown',function(e){
    if(!current)return;
    if(e.key==='Escape')close();else if(e.key==='ArrowRight')step(1);else if(e.key==='ArrowLeft')step(-1);
  });
})();
"""


