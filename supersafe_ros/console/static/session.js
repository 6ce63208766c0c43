// The participant session page: instructions per phase in plain words, the arrow keys
// (Phase I), Space or a click to intervene (Phase II), the fit in words and a drawing,
// the questionnaires, countdowns. The drawing and the WebSocket are console.js's.
//
// Hooks (stable, a test contract): body[data-phase] (welcome, phase1, phase2, fitting, fit,
// game, likert, done, stopped), body[data-waiting], body[data-running], #start, #field,
// #message, #clock (the countdown), #overlay (the pause between scenes),
// input[data-likert], button[data-action="answers"].
'use strict';
(function () {
  const el = (id) => document.getElementById(id);
  const send = (obj) => window.supersafeSend(obj);
  const SVG = 'http://www.w3.org/2000/svg';
  let view = { phase: 'welcome' };
  let pauseEnds = 0;                          // Date.now() when the scene pause ends
  const keys = { left: false, right: false };

  const minutes = (s) => {
    s = Math.max(0, Math.ceil(s));
    return `${Math.floor(s / 60)}:${String(s % 60).padStart(2, '0')}`;
  };
  const duration = (s) => (s >= 60 && s % 60 === 0 ? `${s / 60} minute${s === 60 ? '' : 's'}` : `${s} seconds`);

  const COPY = {
    welcome: () => ['Welcome', ['Thank you for taking part. The study has three parts.',
      'Please wait: the researcher is starting it.']],
    phase1: (v) => ['Part 1 of 3: drive a robot', [
      `For ${duration(v.seconds)} you drive the blue robot. It always moves forward: you only steer.`,
      'Hold the ← key to turn left and the → key to turn right.',
      'Try to drive around the red discs: they are obstacles. Stay on the field: if the robot ' +
      'leaves it, it is shown faded at the edge until you turn it back.']],
    phase2: (v) => ['Part 2 of 3: when would you step in?', [
      'A robot drives straight towards an obstacle. It does not turn by itself.',
      'If you think it is going to hit the obstacle, press the Space bar (or click the field) to stop it: ' +
      'the obstacle disappears.',
      'If you think it will pass by safely, do nothing.',
      `There are ${v.scenes} short scenes, with a pause of 3 seconds between them.`]],
    fitting: () => ['Please wait', ['The robots are learning from your answers. This takes a few seconds.']],
    fit: (v) => ['The robots have learned from you', [v.summary, v.sentence,
      'The drawing shows one obstacle, the places where you stopped the robot, and where a robot ' +
      'coming from the left starts to turn away: before, and from now on.']],
    game: (v) => [`Part 3 of 3: ${v.game} of ${v.of || 3}`, [
      `Two robots, a blue one and an orange one, drive back and forth across the field for ${duration(v.seconds)}. ` +
      'They steer around the obstacles they notice, but they may miss one.',
      'If you think a robot is about to hit an obstacle, click that obstacle to remove it.',
      'Points: +10 each time a robot crosses the field, −20 for each crash, −10 for each obstacle you remove.']],
    likert: (v) => [`Questions about ${v.pair[0]} and ${v.pair[1]}`, [
      `You have played ${v.pair[0]} and ${v.pair[1]} with two robot teams. How much do you agree with each ` +
      `sentence? Answer it once for the team of ${v.pair[0]} and once for the team of ${v.pair[1]}: ` +
      `1 = strongly disagree, 4 = neither, ${v.points} = strongly agree.`]],
    done: () => ['Thank you!', ['The study is complete. Thank you for taking part.',
      'You may close this page.']],
    stopped: () => ['The study is paused', ['The researcher has stopped the program. ' +
      'Please wait: it will go on from where it stopped.']],
  };

  const LEGENDS = {
    phase1: [['swatch', 'var(--blue)', 'your robot (blue)'], ['swatch', 'var(--obstacle)', 'obstacle']],
    phase2: [['swatch', 'var(--blue)', 'the robot'], ['swatch', 'var(--obstacle)', 'obstacle']],
    game: [['swatch', 'var(--blue)', 'blue robot'], ['swatch', 'var(--orange)', 'orange robot'],
           ['swatch', 'var(--obstacle)', 'obstacle (click to remove)']],
    fit: [['swatch dot', '', 'where you stopped the robot'],
          ['swatch line dashed', '#777', 'where robots turned away before'],
          ['swatch line', 'var(--blue)', 'where robots turn away now']],
  };

  function renderLegend(phase) {
    const ul = el('legend');
    ul.innerHTML = '';
    (LEGENDS[phase] || []).forEach(([cls, colour, text]) => {
      const li = document.createElement('li');
      const s = document.createElement('span');
      s.className = cls;
      if (cls.includes('line')) s.style.borderTopColor = colour; else if (colour) s.style.background = colour;
      li.appendChild(s); li.appendChild(document.createTextNode(text));
      ul.appendChild(li);
    });
  }

  // one radio group: name (a test hook: input[data-likert]), its label for screen readers
  function radios(tr, name, label, points) {
    for (let k = 1; k <= points; k++) {
      const td = document.createElement('td');
      const r = document.createElement('input');
      r.type = 'radio'; r.name = name; r.value = k; r.dataset.likert = name;
      r.setAttribute('aria-label', `${label}: ${k}`);
      td.appendChild(r); tr.appendChild(td);
    }
  }

  function scaleHead(table, points, groups) {
    const head = document.createElement('thead');
    const corner = () => { const c = document.createElement('th'); c.className = 'item'; return c; };
    if (groups.length > 1) {
      const gr = document.createElement('tr');
      gr.appendChild(corner());
      groups.forEach((g) => {
        const th = document.createElement('th'); th.colSpan = points; th.className = 'group'; th.textContent = g;
        gr.appendChild(th);
      });
      head.appendChild(gr);
    }
    const hr = document.createElement('tr');
    hr.appendChild(corner());
    groups.forEach(() => {
      for (let k = 1; k <= points; k++) {
        const th = document.createElement('th');
        th.textContent = String(k);
        if (k === 1) th.title = 'strongly disagree';
        if (k === points) th.title = 'strongly agree';
        hr.appendChild(th);
      }
    });
    head.appendChild(hr); table.appendChild(head);
  }

  // the questionnaire after a comparison: each statement rated for both games, then the preference
  function renderLikert(v) {
    const form = el('likert');
    form.innerHTML = '';
    const teams = document.createElement('table');
    teams.className = 'teams';
    scaleHead(teams, v.points, v.pair);
    const body = document.createElement('tbody');
    v.items.forEach((item) => {
      const tr = document.createElement('tr');
      const th = document.createElement('th'); th.className = 'item'; th.scope = 'row'; th.textContent = item.text;
      tr.appendChild(th);
      v.pair.forEach((game, side) => radios(tr, `${item.key}.${side}`, `${game}: ${item.text}`, v.points));
      body.appendChild(tr);
    });
    teams.appendChild(body); form.appendChild(teams);
    const pref = document.createElement('table');
    pref.className = 'preference';
    scaleHead(pref, v.points, ['']);
    const pb = document.createElement('tbody');
    const tr = document.createElement('tr');
    const th = document.createElement('th'); th.className = 'item'; th.scope = 'row'; th.textContent = v.preference.text;
    tr.appendChild(th);
    radios(tr, v.preference.key, v.preference.text, v.points);
    pb.appendChild(tr); pref.appendChild(pb); form.appendChild(pref);
    const b = document.createElement('button');
    b.type = 'submit'; b.textContent = 'Send answers'; b.dataset.action = 'answers';
    form.appendChild(b);
    form.onsubmit = (e) => {
      e.preventDefault();
      const pick = (name) => {
        const c = form.querySelector(`input[name="${name}"]:checked`);
        return c ? parseInt(c.value, 10) : null;
      };
      const values = {};
      let left = 0;
      v.items.forEach((item) => {
        values[item.key] = v.pair.map((_, side) => pick(`${item.key}.${side}`));
        left += values[item.key].filter((x) => x === null).length;
      });
      values[v.preference.key] = pick(v.preference.key);
      if (values[v.preference.key] === null) left += 1;
      if (left) { window.supersafeSay(`Please answer every sentence (${left} left).`, 'error'); return; }
      send({ type: 'answers', values });
    };
  }

  function svg(tag, attrs) {
    const node = document.createElementNS(SVG, tag);
    for (const [k, val] of Object.entries(attrs || {})) node.setAttribute(k, val);
    return node;
  }

  // one Phase II scene, enlarged: the obstacle at the origin, the robot's approach from the left
  function renderFitDrawing(d) {
    const g = el('fit-drawing');
    g.innerHTML = '';
    if (!d) return;
    const scale = 2.6;     // drawn in the scene's metres, enlarged: widths are in those metres
    g.setAttribute('transform', `scale(${scale}) translate(3 0)`);
    const [ox, oy, r] = d.obstacle;
    g.appendChild(svg('line', { class: 'path', x1: -10.5, y1: 0, x2: 3, y2: 0, 'stroke-width': 0.03 }));
    g.appendChild(svg('polygon', { class: 'arrow', points: '-10.6,0.35 -9.9,0 -10.6,-0.35' }));
    g.appendChild(svg('circle', { class: 'fit-obstacle', cx: ox, cy: oy, r }));
    const line = (pts, cls) => pts.length && g.appendChild(svg('polyline', {
      class: cls, points: pts.map((p) => p.join(',')).join(' '), 'stroke-width': 0.07 }));
    line(d.before, 'before');
    line(d.now, 'now');
    d.stops.forEach(([x, y]) => g.appendChild(svg('circle', { class: 'stop', cx: x, cy: y, r: 0.16 })));
  }

  function updateClock() {
    const c = el('clock');
    let text = '';
    const sim = (window.supersafeConsole || {}).simTime || 0;
    if (view.phase === 'phase1' || view.phase === 'game') {
      text = view.running ? `${minutes(view.seconds - sim)} left` : minutes(view.seconds);
    } else if (view.phase === 'phase2' && view.scenes) {
      text = `Scene ${Math.min((view.done || 0) + 1, view.scenes)} of ${view.scenes}`;
    }
    if (c.textContent !== text) c.textContent = text;
    const o = el('overlay');
    const left = (pauseEnds - Date.now()) / 1000;
    const showPause = view.phase === 'phase2' && left > 0;
    if (showPause) {
      const t = `Next scene in ${Math.ceil(left)} s`;
      if (o.textContent !== t) o.textContent = t;
    }
    if (o.hidden === showPause) o.hidden = !showPause;
  }
  setInterval(updateClock, 200);

  function show(v) {
    if (v.phase !== view.phase) window.supersafeSay('');
    view = v;
    document.body.dataset.phase = v.phase;
    document.body.dataset.waiting = v.waiting ? 'true' : 'false';
    document.body.dataset.running = v.running ? 'true' : 'false';
    if (v.phase === 'phase2') pauseEnds = Date.now() + 1000 * (v.pause || 0);
    const [title, paragraphs] = (COPY[v.phase] || (() => [v.phase, []]))(v);
    el('phase-title').textContent = title;
    const text = el('phase-text');
    text.innerHTML = '';
    paragraphs.concat(v.waiting ? [v.phase === 'fit' ? 'Press Continue when you are ready for the games.'
      : 'Press Start when you are ready.'] : []).forEach((p) => {
      if (!p) return;
      const para = document.createElement('p'); para.textContent = p; text.appendChild(para);
    });
    renderLegend(v.phase);
    const start = el('start');
    start.hidden = !v.waiting;
    start.disabled = false;
    start.textContent = v.phase === 'fit' ? 'Continue' : 'Start';
    renderFitDrawing(v.phase === 'fit' ? v.drawing : null);
    const likert = el('likert');
    likert.hidden = v.phase !== 'likert';
    // once per questionnaire: a reconnect (which shows the view again) keeps the choices made
    if (v.phase !== 'likert') delete likert.dataset.pair;
    else if (likert.dataset.pair !== String(v.pair)) { renderLikert(v); likert.dataset.pair = String(v.pair); }
    if (v.waiting) start.focus();
    updateClock();
  }

  // crashes are marked in Phase I and the games; a calibration scene lets the robot through
  window.supersafeShowCrashes = () => view.phase === 'phase1' || view.phase === 'game';

  // the end: the page's own calm screen says it all (no banner when the program then closes)
  window.supersafeBannerText = () => (view.phase === 'done'
    ? ''
    : view.phase === 'stopped'
      ? 'The study is paused: the researcher has stopped the program. Please wait; this page reconnects by itself.'
      : 'The connection to the study computer is lost. The page keeps trying to reconnect; ' +
        'if this message stays, please tell the researcher.');

  // one Start per screen: a double click must not start the next phase unseen
  el('start').addEventListener('click', () => {
    el('start').disabled = true;
    send({ type: 'start', phase: view.phase });
  });

  function interveneOnTheObstacle() {
    const o = document.querySelector('[data-obstacle-id]');
    if (o) o.dispatchEvent(new MouseEvent('click', { bubbles: true }));
    return !!o;
  }
  // Phase II: a click anywhere on the field is the Space bar
  window.supersafeEmptyClick = () => {
    if (view.phase === 'phase2') {
      if (!interveneOnTheObstacle()) window.supersafeSay('No obstacle right now: wait for the next scene.');
      return true;
    }
    if (view.phase !== 'game') return true;     // nothing to click in the other phases
    return false;
  };

  function setKey(e, down) {
    if (view.phase === 'phase1' && (e.key === 'ArrowLeft' || e.key === 'ArrowRight')) {
      e.preventDefault();
      const k = e.key === 'ArrowLeft' ? 'left' : 'right';
      if (keys[k] !== down) { keys[k] = down; send({ type: 'keys', left: keys.left, right: keys.right }); }
    }
    if (down && view.phase === 'phase2' && !view.waiting && (e.key === ' ' || e.code === 'Space')) {
      e.preventDefault();
      if (!e.repeat && !interveneOnTheObstacle()) window.supersafeSay('No obstacle right now: wait for the next scene.');
    }
  }
  document.addEventListener('keydown', (e) => setKey(e, true));
  document.addEventListener('keyup', (e) => setKey(e, false));
  window.addEventListener('blur', () => {        // a key held while the window loses focus
    if (keys.left || keys.right) { keys.left = keys.right = false; send({ type: 'keys', left: false, right: false }); }
  });

  document.addEventListener('supersafe-message', (e) => {
    const msg = e.detail;
    if (msg.type === 'hello' && msg.session) show(msg.session);
    else if (msg.type === 'session') show(msg);
    else if (msg.type === 'session_ack' && view.phase === 'likert') window.supersafeSay('Thank you.');
  });
})();
