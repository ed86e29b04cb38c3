// Starts Foxglove Studio's App (the bundle's exports are globals) as its web app does, with
// an in-memory layout store holding the layout served at /layout.json (id "cosim") and the
// remote-file data source, so that ?ds=remote-file&ds.url=...&layoutId=cosim opens a run, and
// the Foxglove WebSocket one (?ds=foxglove-websocket&ds.url=ws://...) for a live view.
(async () => {
  const S = window;
  const layout = await (await fetch("/layout.json")).json();
  const saved = new Date().toISOString();
  const layouts = new Map([["cosim", {
    id: "cosim", name: "cosim", permission: "CREATOR_WRITE",
    baseline: { data: layout, savedAt: saved }, working: undefined, syncInfo: undefined }]]);
  const layoutStorage = {
    async list() { return [...layouts.values()]; },
    async get(_ns, id) { return layouts.get(id); },
    async put(_ns, l) { layouts.set(l.id, l); return l; },
    async delete(_ns, id) { layouts.delete(id); },
    async importLayouts() {},
    async migrateUnnamespacedLayouts() {},
  };
  const values = new Map();
  const listeners = new Map();
  const appConfiguration = {
    get: (k) => values.get(k),
    async set(k, v) { values.set(k, v); (listeners.get(k) || []).forEach((cb) => cb(v)); },
    addChangeListener(k, cb) { listeners.set(k, [...(listeners.get(k) || []), cb]); },
    removeChangeListener(k, cb) { listeners.set(k, (listeners.get(k) || []).filter((c) => c !== cb)); },
  };
  localStorage.setItem("studio.profile-data", JSON.stringify({ currentLayoutId: "cosim" }));
  await S.initI18n();
  S.ReactDOM.render(S.React.createElement(S.App, {
    deepLinks: [window.location.href],
    appConfiguration,
    dataSources: [new S.RemoteDataSourceFactory(), new S.McapLocalDataSourceFactory(),
      new S.FoxgloveWebSocketDataSourceFactory()],
    layoutStorage,
    extensionLoaders: [],
    enableGlobalCss: true,
  }), document.getElementById("root"));
  window.cosimBooted = true;
})().catch((e) => { window.cosimBootError = String(e && e.stack || e); });
