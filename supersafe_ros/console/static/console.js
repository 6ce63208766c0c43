// The supervisor console page: draws what the server sends and turns clicks on
// obstacles into interventions. No framework, no build step.
//
// Hooks for tests, screen readers and scripts (stable):
//   [data-obstacle-id="<id>"]  one element per obstacle (click, Enter or Space = intervention)
//   [data-robot="<ns>"]        one element per robot (data-x, data-y, data-theta: its pose;
//                              data-colour: its colour's name)
//   [data-crash="<n>"]         a crash mark on the field (recent crashes)
//   [data-stat="score|trips|crashes|interventions"]  text = the number
//   #message                   the line that answers every click
//   body[data-connected]       'true' while the page's WebSocket is open (opened once the
//                              page and all its scripts have loaded)
//   window.supersafeConsole    counters: messages, renders, removals (click -> gone, ms), simTime
'use strict';
(function () {
  const SVG = 'http://www.w3.org/2000/svg';
  const COLORS = ['#1f5fa8', '#e08a00', '#6a3d9a', '#1b9e77', '#d95f02', '#7570b3',
                  '#e7298a', '#66a61e', '#a6761d', '#444444'];
  const COLOUR_NAMES = ['blue', 'orange', 'purple', 'green', 'red', 'violet', 'pink', 'lime',
                        'brown', 'grey'];
  const CRASH_SHOWN_S = 6.0;          // sim seconds a crash mark stays on the field
  const perf = {
    messages: 0, renders: 0, errors: [], replies: [],
    clicks: {},        // obstacle id -> Date.now() of the click
    removals: {},      // obstacle id -> ms from click to the element leaving the page
    connected: false, simTime: 0,
  };
  window.supersafeConsole = perf;

  const el = (id) => document.getElementById(id);
  let field = null, trailLength = 40, ws = null;
  let pending = null;                 // newest state not drawn yet
  let lastCrash = null;               // newest crash id announced on the message line
  const trails = {};                  // robot -> [[x, y], ...]
  const robotEls = {}, trailEls = {};
  const obstacleEls = new Map();
  const crashEls = new Map();

  function svg(tag, attrs) {
    const node = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
    return node;
  }

  function colourIndex(name, fallback) {
    const m = /_(\d+)$/.exec(name);
    return m ? parseInt(m[1], 10) : fallback;
  }
  function colourName(name) {
    return COLOUR_NAMES[colourIndex(name, Object.keys(robotEls).indexOf(name)) % COLOUR_NAMES.length];
  }
  window.supersafeColourName = colourName;
  window.supersafeColours = { COLORS, COLOUR_NAMES };

  let sayTimer = null;
  function say(text, kind) {
    const m = el('message');
    m.textContent = text;
    if (!text) { m.classList.remove('error', 'crash', 'fresh'); return; }
    m.classList.toggle('error', kind === 'error');
    m.classList.toggle('crash', kind === 'crash');
    m.classList.add('fresh');
    clearTimeout(sayTimer);
    sayTimer = setTimeout(() => m.classList.remove('fresh'), 1500);
  }
  window.supersafeSay = say;

  function setupField(f) {
    field = f;
    const w = f.half_width, h = f.half_height;
    el('field').setAttribute('viewBox', `${-w} ${-h} ${2 * w} ${2 * h}`);
    el('world').setAttribute('transform', 'scale(1,-1)');
    const g = el('ground');
    for (const [k, v] of Object.entries({ x: -w, y: -h, width: 2 * w, height: 2 * h })) g.setAttribute(k, v);
    for (const [id, x] of [['goal-left', -f.goal_x], ['goal-right', f.goal_x]]) {
      const line = el(id);
      for (const [k, v] of Object.entries({ x1: x, x2: x, y1: -h, y2: h })) line.setAttribute(k, v);
    }
  }

  function robotElement(name, index) {
    const ci = colourIndex(name, index);
    const color = COLORS[ci % COLORS.length];
    const cname = COLOUR_NAMES[ci % COLOUR_NAMES.length];
    const g = svg('g', { class: 'robot', 'data-robot': name, 'data-colour': cname,
                         'aria-label': `${cname} robot` });
    const title = svg('title'); title.textContent = `${cname} robot (${name})`; g.appendChild(title);
    // an arrow pointing along +x (the heading), about a robot's size
    g.appendChild(svg('polygon', { class: 'robot-body', points: '0.9,0 -0.6,0.55 -0.3,0 -0.6,-0.55', fill: color }));
    el('robots').appendChild(g);
    const trail = svg('polyline', { class: 'trail', 'data-trail': name, stroke: color, points: '' });
    el('trails').appendChild(trail);
    robotEls[name] = g; trailEls[name] = trail; trails[name] = [];
  }

  function drawRobots(robots) {
    // robots of an earlier graph (the session's phases) that this one does not have
    for (const [name, g] of Object.entries(robotEls)) {
      const here = name in robots;
      if ((g.getAttribute('visibility') !== 'hidden') !== here) {
        g.setAttribute('visibility', here ? 'visible' : 'hidden');
        trailEls[name].setAttribute('visibility', here ? 'visible' : 'hidden');
        if (!here) { trails[name].length = 0; trailEls[name].setAttribute('points', ''); }
      }
    }
    let i = Object.keys(robotEls).length;
    for (const [name, p] of Object.entries(robots)) {
      if (!robotEls[name]) robotElement(name, i++);
      const [x, y, th] = p;
      const g = robotEls[name];
      // a robot that has driven off the field (Phase I's free driving) stays in sight at its edge
      const w = field ? field.half_width - 0.6 : Infinity, h = field ? field.half_height - 0.6 : Infinity;
      const cx = Math.max(-w, Math.min(w, x)), cy = Math.max(-h, Math.min(h, y));
      g.classList.toggle('off-field', cx !== x || cy !== y);
      g.setAttribute('transform', `translate(${cx} ${cy}) rotate(${(th * 180 / Math.PI).toFixed(1)})`);
      g.setAttribute('data-x', x); g.setAttribute('data-y', y); g.setAttribute('data-theta', th);
      const t = trails[name];
      const last = t[t.length - 1];
      if (!last || Math.hypot(last[0] - x, last[1] - y) > 0.25) {
        // a jump (scene reset, teleport) starts a new trail
        if (last && Math.hypot(last[0] - x, last[1] - y) > 5) t.length = 0;
        t.push([x, y]);
        if (t.length > trailLength) t.shift();
        trailEls[name].setAttribute('points', t.map((q) => q.join(',')).join(' '));
      }
    }
  }

  function drawObstacles(list) {
    const seen = new Set();
    for (const [id, x, y, r] of list) {
      seen.add(id);
      let c = obstacleEls.get(id);
      if (!c) {
        c = svg('circle', { class: 'obstacle', 'data-obstacle-id': id, tabindex: 0, role: 'button',
                            'aria-label': `obstacle ${id}: remove` });
        c.addEventListener('click', (e) => { e.stopPropagation(); intervene(id); });
        c.addEventListener('keydown', (e) => {
          if (e.key === 'Enter' || e.key === ' ') { e.preventDefault(); e.stopPropagation(); intervene(id); }
        });
        el('obstacles').appendChild(c);
        obstacleEls.set(id, c);
      }
      c.setAttribute('cx', x); c.setAttribute('cy', y); c.setAttribute('r', r);
    }
    let focusLost = false;
    for (const [id, c] of obstacleEls) {
      if (!seen.has(id)) {
        focusLost = focusLost || document.activeElement === c;
        c.remove();
        obstacleEls.delete(id);
        if (perf.clicks[id] !== undefined) perf.removals[id] = Date.now() - perf.clicks[id];
      }
    }
    if (focusLost) {
      // keyboard users keep their place: the next obstacle (or the field) takes the focus
      const next = obstacleEls.values().next().value;
      (next || el('field')).focus();
    }
  }

  function drawCrashes(events) {
    const keep = new Set();
    const shown = !window.supersafeShowCrashes || window.supersafeShowCrashes();
    for (const ev of events) {
      if (!shown || ev.kind !== 'crash' || perf.simTime - ev.time > CRASH_SHOWN_S) continue;
      keep.add(ev.id);
      if (!crashEls.has(ev.id)) {
        const g = svg('g', { class: 'crash-mark', 'data-crash': ev.id, transform: `translate(${ev.x} ${ev.y})`,
                             'aria-label': `crash of the ${colourName(ev.robot)} robot` });
        g.appendChild(svg('circle', { r: 1.1 }));
        g.appendChild(svg('path', { d: 'M -0.8 -0.8 L 0.8 0.8 M -0.8 0.8 L 0.8 -0.8' }));
        el('marks').appendChild(g);
        crashEls.set(ev.id, g);
      }
      if (lastCrash !== null && ev.id > lastCrash) {
        say(`Crash: the ${colourName(ev.robot)} robot hit an obstacle.`, 'crash');
      }
    }
    for (const [id, g] of crashEls) {
      if (!keep.has(id)) { g.remove(); crashEls.delete(id); }
    }
    lastCrash = events.reduce((m, ev) => Math.max(m, ev.id), lastCrash === null ? 0 : lastCrash);
  }

  function drawStats(stats) {
    for (const [k, v] of Object.entries(stats)) {
      const d = document.querySelector(`[data-stat="${k}"]`);
      if (d && d.textContent !== String(v)) d.textContent = String(v);
    }
  }

  let events = [];
  function render() {
    const s = pending;
    pending = null;
    if (!s) return;
    if (s.sim_time !== undefined) perf.simTime = s.sim_time;
    if (s.obstacles) drawObstacles(s.obstacles);
    if (s.robots) drawRobots(s.robots);
    if (s.stats) drawStats(s.stats);
    if (s.events) events = s.events;
    drawCrashes(events);
    perf.renders++;
  }

  function schedule(state) {
    // several messages between two frames: keep the newest poses, and any obstacle,
    // stats or events part (a later message may carry none)
    if (pending) {
      state.obstacles = state.obstacles || pending.obstacles;
      state.stats = state.stats || pending.stats;
      state.events = state.events || pending.events;
    }
    const first = !pending;
    pending = state;
    if (first) requestAnimationFrame(render);
  }

  function intervene(id) {
    if (!ws || ws.readyState !== WebSocket.OPEN) { say('Not connected: the click was not sent.', 'error'); return; }
    perf.clicks[id] = Date.now();
    ws.send(JSON.stringify({ type: 'intervene', obstacle: id, ref: perf.clicks[id] }));
  }

  el('field').addEventListener('click', (e) => {
    if (e.target.hasAttribute && e.target.hasAttribute('data-obstacle-id')) return;
    if (window.supersafeEmptyClick && window.supersafeEmptyClick(e)) return;
    say('That was not an obstacle: click on a red disc to remove it.');
  });

  function onMessage(ev) {
    let msg;
    try { msg = JSON.parse(ev.data); } catch (e) { return; }
    perf.messages++;
    if (msg.type === 'hello') {
      setupField(msg.field);
      if (msg.config && msg.config.trail_length !== undefined) trailLength = msg.config.trail_length;
      msg.robots.forEach((r, i) => { if (!robotEls[r]) robotElement(r, i); });
      lastCrash = (msg.state.events || []).reduce((m, e) => Math.max(m, e.id), 0);
      schedule(msg.state);
    } else if (msg.type === 'state') {
      schedule(msg);
    } else if (msg.type === 'intervention') {
      perf.replies.push(msg);
      if (msg.ok) {
        const who = msg.robot && msg.robot !== 'unknown' ? ` (the ${colourName(msg.robot)} robot was nearest)` : '';
        say(`Obstacle removed${who}.`);
      } else say(msg.message, 'error');
    } else if (msg.type === 'error') {
      perf.errors.push(msg.message);
      say(`The page sent something the console did not accept: ${msg.message}`, 'error');
    }
    document.dispatchEvent(new CustomEvent('supersafe-message', { detail: msg }));
  }

  function banner(show) {
    let b = el('banner');
    if (!b) {
      b = document.createElement('div');
      b.id = 'banner'; b.className = 'banner'; b.setAttribute('role', 'alert');
      document.body.prepend(b);
    }
    const text = window.supersafeBannerText ? window.supersafeBannerText() :
      'The connection to the study computer is lost. The page keeps trying to reconnect; ' +
      'if this message stays, please tell the researcher.';
    b.textContent = text;
    b.hidden = !show || !text;        // '' : the page says it in its own words (the end of a session)
  }

  function connect() {
    const token = new URLSearchParams(location.search).get('token');
    const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws` +
      (token ? `?token=${encodeURIComponent(token)}` : '');
    ws = new WebSocket(url);
    perf.ws = ws;
    ws.onopen = () => {
      perf.connected = true;
      document.body.dataset.connected = 'true';
      ws.send(JSON.stringify({ type: 'watch' }));
      banner(false);
      const c = el('connection'); c.textContent = 'connected'; c.classList.add('live');
    };
    ws.onmessage = onMessage;
    ws.onclose = () => {
      perf.connected = false;
      document.body.dataset.connected = 'false';
      banner(true);
      const c = el('connection'); c.textContent = 'not connected'; c.classList.remove('live');
      setTimeout(connect, 1000);
    };
  }

  window.supersafeSend = (obj) => ws && ws.readyState === WebSocket.OPEN && ws.send(JSON.stringify(obj));
  document.body.dataset.connected = 'false';
  // the page's other scripts (session.js) listen for 'supersafe-message': the first message
  // (hello, with the session's screen) must not arrive before they have loaded and run
  if (document.readyState === 'complete') connect();
  else window.addEventListener('load', connect, { once: true });
})();
